"""A plant's year in PostgreSQL (issue 27): 20 benches, 500 000 runs with their results, the samples of a share of
them, and the fleet API measured on it: the list (newest first, deep pages), its filters, a run's page (the test
and its loop), SPC over 10 000 runs, and exports.

    python -m benchmarks --only plant_scale          # the README's figures (minutes: the fill, then 3 rounds)
    python -m benchmarks.plant_scale --runs 50000    # a smaller plant, printed as JSON

* The server: a throwaway PostgreSQL (``initdb`` in a temporary directory, as user postgres when root;
  :class:`~tcms_daq.store.pgserver.ThrowawayPostgres`) with 256 MB of shared buffers; fsync off during the fill
  only matters to a crash of the server, not to the reads measured.
* The year is filled in SQL, not row by row: one real test on the simulated bench through ``tcms serve`` is the
  template (its request, profile, whole results — about 15 kB of JSON — and their brief, config snapshot,
  compensator and samples); ``generate_series`` makes 500 000 runs from it over a year (20 benches, the catalogue's reducer
  models, serial numbers, operators; 2 % aborted or failed; each completed run's headline results drawn around
  its model's catalogue rigidity with the run's pass/fail/undecided verdict), and ``INSERT … SELECT`` gives a
  share of the completed runs the template's samples, in the month partitions of the runs.
* The API is ``tcms serve`` on that store in its own process, asked over HTTP (keep-alive) by this process: each
  request kind ``REQUESTS`` times per round (its parameters drawn anew: a bench, a serial number, a run …),
  after a warm-up; p50 and p95 per round, min/median/max over 3 rounds.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import httpx

from benchmarks._runs import RUNS, spread
from tcms_daq.store.pgserver import ThrowawayPostgres, pg_bin_dir

BENCHES = 20
RUNS_PER_YEAR = 500_000
SAMPLE_SHARE = 0.005  # of the completed runs, with the template's samples (0.5 %: 2 500 runs of a year)
REQUESTS = 40  # timed requests per kind and round
YEAR_S = 365 * 86400.0
TOKEN = "plant-scale-token"
P95_LIMIT_S = 0.2  # the target for the list, its filters and SPC
OPERATORS = 30
REFERENCE = "reference"  # GET /api/health: the HTTP round trip and the framework, no store; the ratios' unit


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _start_service(url: str, data_dir: Path) -> tuple[subprocess.Popen[str], httpx.Client]:
    port = _free_port()
    env = {**os.environ, "TCMS_API_TOKEN": TOKEN}
    proc = subprocess.Popen([sys.executable, "-m", "tcms_daq.cli", "serve", "--port", str(port), "--data-dir",
                             str(data_dir), "--store", url, "--sim-speed", "100", "--log-level", "warning"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"},
                          timeout=120)
    deadline = time.monotonic() + 120
    while True:
        try:
            if client.get("/api/health").status_code == 200:
                return proc, client
        except httpx.HTTPError:
            pass
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"tcms serve did not answer: {proc.stderr.read()[-2000:] if proc.stderr else ''}")
        time.sleep(0.3)


def _template_run(client: httpx.Client) -> str:
    """One real test on the simulated bench: the run the year is made of."""
    run_id = client.post("/api/tests", json={"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 2,
                                             "rate_nm_per_s": 200, "serial_number": "TEMPLATE",
                                             "operator": "template"}).json()["id"]
    deadline = time.monotonic() + 600
    while (status := client.get(f"/api/tests/{run_id}").json()["status"]) in ("queued", "running"):
        if time.monotonic() > deadline:
            raise RuntimeError("the template test did not end within 600 s")
        time.sleep(0.5)
    if status != "completed":
        raise RuntimeError(f"the template test ended {status}")
    return run_id


_FILL_RUNS = """
INSERT INTO runs (id, created_at, started_at, finished_at, status, request, profile, results, error, config_snapshot,
                  compensator_toml, channels, sample_count, compensation_version, bench_id, bench_name, reducer,
                  serial_number, operator, verdict, rigidity_nm_per_arcmin, lost_motion_arcsec, backlash_arcsec,
                  test_series, results_brief)
SELECT v.id, v.created, v.created + 2, v.created + 62, v.status,
       t.request || jsonb_build_object('reducer', v.reducer, 'serial_number', v.serial, 'operator', v.operator),
       t.profile,
       CASE WHEN v.status = 'completed' THEN jsonb_set(t.results || jsonb_build_object(
            'rigidity_nm_per_arcmin', v.rigidity, 'lost_motion_arcsec', v.lost_motion, 'backlash_arcsec', v.backlash),
            '{verdict,decision}', to_jsonb(v.verdict)) END,
       CASE WHEN v.status = 'failed' THEN 'instrument fault: no reading for 4.0 s' END,
       t.config_snapshot, t.compensator_toml, t.channels, 0, NULL, v.bench_id, 'Bench ' || v.bench_no,
       v.reducer, v.serial, v.operator,
       CASE WHEN v.status = 'completed' THEN v.verdict END,
       CASE WHEN v.status = 'completed' THEN v.rigidity END,
       CASE WHEN v.status = 'completed' THEN v.lost_motion END,
       CASE WHEN v.status = 'completed' THEN v.backlash END,
       t.test_series,
       CASE WHEN v.status = 'completed' THEN jsonb_set(t.results_brief || jsonb_build_object(
            'rigidity_nm_per_arcmin', v.rigidity, 'lost_motion_arcsec', v.lost_motion, 'backlash_arcsec', v.backlash),
            '{verdict,decision}', to_jsonb(v.verdict)) END
FROM template t, generate_series(%(first)s::int, %(last)s::int) AS i, LATERAL (
    SELECT 'y' || lpad(i::text, 7, '0') AS id,
           %(t0)s + (i - 1) * %(step)s + random() * %(step)s AS created,
           CASE WHEN i %% 61 = 0 THEN 'aborted' WHEN i %% 97 = 0 THEN 'failed' ELSE 'completed' END AS status,
           (i %% %(benches)s) + 1 AS bench_no,
           'bench-' || lpad(((i %% %(benches)s) + 1)::text, 2, '0') AS bench_id,
           m.name AS reducer,
           'SN-' || lpad(i::text, 7, '0') AS serial,
           'operator-' || (i %% %(operators)s) AS operator,
           round((m.rigidity * (1 + 0.03 * sqrt(-2 * ln(1 - random())) * cos(2 * pi() * random())))::numeric, 3
                 )::double precision AS rigidity,
           round((20 + 10 * random())::numeric, 2)::double precision AS lost_motion,
           round((18 + 12 * random())::numeric, 2)::double precision AS backlash,
           CASE WHEN i %% 29 = 0 THEN 'fail' WHEN i %% 31 = 0 THEN 'undecided' ELSE 'pass' END AS verdict
    FROM (SELECT name, rigidity FROM models WHERE ord = i %% %(models)s) AS m
) AS v
"""


def _fill(url: str, template_id: str, n_runs: int, sample_share: float, t0: float,
          progress: Callable[[str], None]) -> dict[str, float]:
    import psycopg
    from psycopg import sql

    from tcms_daq.config.loader import load_reducer_catalogue

    models = sorted((name, spec.rigidity_nm_per_arcmin) for name, spec in load_reducer_catalogue().items()
                    if spec.rigidity_nm_per_arcmin)
    started = time.perf_counter()
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("CREATE UNLOGGED TABLE template AS SELECT * FROM runs WHERE id = %s", (template_id,))
        conn.execute("CREATE UNLOGGED TABLE models (ord int, name text, rigidity double precision)")
        with conn.cursor() as cur:
            cur.executemany("INSERT INTO models VALUES (%s, %s, %s)",
                            [(i, name, rig) for i, (name, rig) in enumerate(models)])
        # the runs' secondary indexes are made again after the fill (faster than kept up row by row)
        indexes = [r[0] for r in conn.execute("SELECT indexdef FROM pg_indexes WHERE tablename = 'runs' AND "
                                              "indexname <> 'runs_pkey'")]
        for name in [r[0] for r in conn.execute("SELECT indexname FROM pg_indexes WHERE tablename = 'runs' AND "
                                                "indexname <> 'runs_pkey'")]:
            conn.execute(sql.SQL("DROP INDEX {}").format(sql.Identifier(name)))
        step = YEAR_S / n_runs
        for k in range(13):  # the year's month partitions, made once rather than by 500 000 calls
            conn.execute("SELECT tcms_sample_partition(%s)", (t0 + k * YEAR_S / 12,))
        chunk = 50_000
        for first in range(1, n_runs + 1, chunk):
            last = min(n_runs, first + chunk - 1)
            conn.execute(_FILL_RUNS, {"t0": t0, "step": step, "benches": BENCHES, "operators": OPERATORS,
                                      "models": len(models), "first": first, "last": last})  # type: ignore[arg-type]
            progress(f"runs {last}/{n_runs} ({time.perf_counter() - started:.0f} s)")
        for definition in indexes:
            conn.execute(definition)  # type: ignore[arg-type]  # the server's own index definitions
        runs_s = time.perf_counter() - started
        progress(f"indexes made again ({runs_s:.0f} s)")
        every = max(1, round(1 / sample_share)) if sample_share > 0 else 0
        if every:
            row = conn.execute(
                "WITH chosen AS (UPDATE runs SET sample_count = t.sample_count FROM template t "
                "WHERE runs.id LIKE 'y%%' AND runs.status = 'completed' AND substr(runs.id, 2)::int %% %s = 0 "
                "RETURNING runs.id, runs.created_at) "
                "INSERT INTO sample_batches (run_id, run_created_at, batch_index, n_samples, data) "
                "SELECT c.id, c.created_at, b.batch_index, b.n_samples, b.data FROM chosen c "
                "CROSS JOIN (SELECT batch_index, n_samples, data FROM sample_batches WHERE run_id = %s) b "
                "RETURNING 1", (every, template_id)).rowcount
            progress(f"samples: {row} batches ({time.perf_counter() - started:.0f} s)")
        conn.execute("DROP TABLE template")
        conn.execute("DROP TABLE models")
        conn.execute("VACUUM ANALYZE")
    return {"fill_s": time.perf_counter() - started, "fill_runs_s": runs_s}


def _sizes(url: str) -> dict[str, float]:
    """The plant database's runs with samples and its sizes on disk."""
    import psycopg

    with psycopg.connect(url) as conn:
        row = conn.execute("SELECT (SELECT count(*) FROM runs WHERE id LIKE 'y%%' AND sample_count > 0), "
                           "pg_total_relation_size('runs'), (SELECT COALESCE(sum(pg_total_relation_size("
                           "name::regclass)), 0) FROM sample_partitions)").fetchone()
    assert row is not None
    return {"runs_with_samples": float(row[0]), "runs_table_gb": row[1] / 2**30, "samples_gb": float(row[2]) / 2**30}


def _timed(client: httpx.Client, paths: list[str]) -> list[float]:
    out = []
    for path in paths:
        started = time.perf_counter()
        answer = client.get(path)
        answer.read()
        elapsed = time.perf_counter() - started
        if answer.status_code != 200:
            raise RuntimeError(f"GET {path}: {answer.status_code} {answer.text[:300]}")
        out.append(elapsed)
    return out


def _p95(values: list[float]) -> float:
    return statistics.quantiles(values, n=20, method="inclusive")[-1]


def _round(client: httpx.Client, rng: random.Random, n_runs: int, sampled: list[str], reducers: list[str],
           t0: float, requests: int) -> dict[str, dict[str, float]]:
    def bench() -> str:
        return f"bench-{rng.randrange(1, BENCHES + 1):02d}"

    def some_run() -> str:
        return f"y{rng.randrange(1, n_runs + 1):07d}"

    def week() -> str:
        since = t0 + rng.random() * (YEAR_S - 7 * 86400)
        return (f"since={time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(since))}"
                f"&until={time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(since + 7 * 86400))}")

    page = "/api/tests?limit=100&brief=true"  # a page of the fleet page's list
    kinds: dict[str, Callable[[], list[str]]] = {
        REFERENCE: lambda: ["/api/health"],
        "list": lambda: [f"{page}"],
        "list_page_100": lambda: [f"{page}&offset={100 * rng.randrange(90, 110)}"],
        "list_whole_results": lambda: ["/api/tests?limit=100"],
        "filter_bench": lambda: [f"{page}&bench={bench()}"],
        "filter_reducer_verdict": lambda: [f"{page}&reducer={rng.choice(reducers)}&verdict=fail"],
        "filter_serial": lambda: [f"{page}&serial=SN-{rng.randrange(1, n_runs + 1):07d}"],
        "filter_week": lambda: [f"{page}&{week()}"],
        "filter_text": lambda: [f"{page}&q=SN-{rng.randrange(1, n_runs // 100):05d}"],
        "run_page": lambda: [f"/api/tests/{(run := rng.choice(sampled))}", f"/api/tests/{run}/loop"],
        "run_record": lambda: [f"/api/tests/{some_run()}"],
        "spc_chart": lambda: [f"/api/spc/chart?reducer={rng.choice(reducers)}"],
        "export_csv": lambda: [f"/api/tests/{rng.choice(sampled)}/samples?format=csv"],
        "export_parquet": lambda: [f"/api/tests/{rng.choice(sampled)}/samples?format=parquet"],
    }
    figures: dict[str, dict[str, float]] = {}
    for kind, make in kinds.items():
        _timed(client, make())  # warm-up (the first request of a kind plans its queries)
        times = [sum(_timed(client, make())) for _ in range(requests)]
        figures[kind] = {"p50_s": statistics.median(times), "p95_s": _p95(times)}
    reference = figures[REFERENCE]
    for figure in figures.values():  # against the cheap request of the same round: the load divides out
        figure.update(p50_ratio=figure["p50_s"] / reference["p50_s"], p95_ratio=figure["p95_s"] / reference["p95_s"])
    return figures


def _measure(client: httpx.Client, url: str, rounds: int, requests: int,
             progress: Callable[[str], None]) -> tuple[dict[str, float], list[dict[str, dict[str, float]]]]:
    """The rounds of requests on a filled plant database (the year's runs are those whose id starts with y)."""
    import psycopg

    with psycopg.connect(url) as conn:
        sampled = [r[0] for r in conn.execute("SELECT id FROM runs WHERE id LIKE 'y%%' AND sample_count > 0 ORDER BY id")]
        reducers = [r[0] for r in conn.execute("SELECT DISTINCT reducer FROM runs WHERE id LIKE 'y%%'")]
        n_runs, t0, samples_per_run = conn.execute(
            "SELECT count(*), min(created_at), max(sample_count) FROM runs WHERE id LIKE 'y%%'").fetchone()  # type: ignore[misc]
    found = {"runs": float(n_runs), "samples_per_sampled_run": float(samples_per_run),
             "spc_points": float(len(client.get(f"/api/spc/chart?reducer={reducers[0]}").json()["runs"]))}
    rng = random.Random(27)
    per_round = []
    for k in range(rounds):
        progress(f"round {k + 1}/{rounds}")
        per_round.append(_round(client, rng, int(n_runs), sampled, reducers, float(t0), requests))
    return found, per_round


def run(quick: bool = False, n_runs: int | None = None, sample_share: float = SAMPLE_SHARE,
        rounds: int = RUNS, requests: int = REQUESTS, url: str | None = None) -> dict:
    """Fill a throwaway PostgreSQL with a plant's year and measure the fleet API on it; with ``url``, measure an
    existing plant database instead (one an earlier fill made: its pending migrations are applied first)."""
    bin_dir = pg_bin_dir()
    if bin_dir is None and url is None:
        raise RuntimeError("no PostgreSQL server binaries: run `bash scripts/setup --test`")
    n_runs = n_runs or (20_000 if quick else RUNS_PER_YEAR)
    if quick:
        rounds, requests = 1, 10

    def progress(text: str) -> None:
        print(f"[plant_scale] {text}", file=sys.stderr, flush=True)

    t0 = time.time() - YEAR_S - 86400  # the year that ended yesterday
    metrics: dict[str, float] = {"benches": BENCHES, "sample_share": sample_share, "rounds": rounds,
                                 "requests_per_kind": requests}
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="tcms-plant-"))
        fill = url is None
        if url is None:
            import psycopg

            assert bin_dir is not None
            server = stack.enter_context(ThrowawayPostgres(bin_dir, settings={"shared_buffers": "256MB",
                                                                              "max_wal_size": "4GB"}))
            with psycopg.connect(server.url(), autocommit=True) as conn:
                conn.execute("CREATE DATABASE plant")
            url = server.url("plant")
        else:
            from tcms_daq.store.postgres_store import PostgresRunStore

            progress("the store's pending migrations")
            PostgresRunStore(url, recover=False).close()
        proc, client = _start_service(url, Path(tmp))
        try:
            if fill:
                progress("the template: one real test on the simulated bench")
                template_id = _template_run(client)
                metrics.update(_fill(url, template_id, n_runs, sample_share, t0, progress))
            metrics.update(_sizes(url))
            found, per_round = _measure(client, url, rounds, requests, progress)
            metrics.update(found)
        finally:
            client.close()
            proc.terminate()
            proc.wait(30)
    for kind in per_round[0]:
        for figure in ("p50_s", "p95_s", "p50_ratio", "p95_ratio"):
            metrics.update(spread(f"{kind}_{figure}", [r[kind][figure] for r in per_round]))
    gated = [k for k in per_round[0] if k.startswith(("list", "filter", "spc")) and k != "list_whole_results"]
    targets = {f"{k}_p95_s_max": {"limit": P95_LIMIT_S, "met": metrics[f"{k}_p95_s_max"] < P95_LIMIT_S}
               for k in gated}
    return {
        "name": "plant_scale",
        "metrics": metrics,
        "targets": targets,
        "notes": (f"{metrics['runs']:.0f} runs over a year on {BENCHES} benches in a throwaway PostgreSQL "
                  "(shared_buffers 256MB), results of one real test as the template (~15 kB of JSON each), samples "
                  f"for {metrics['runs_with_samples']:.0f} runs ({metrics['samples_per_sampled_run']:.0f} samples "
                  "each) in month partitions; tcms serve in its own process asked over HTTP; p50/p95 of "
                  f"{requests} requests per kind per round, min/median/max of {rounds} rounds; ratios to "
                  "GET /api/health in the same round"),
    }


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=RUNS_PER_YEAR)
    parser.add_argument("--sample-share", type=float, default=SAMPLE_SHARE)
    parser.add_argument("--rounds", type=int, default=RUNS)
    parser.add_argument("--requests", type=int, default=REQUESTS)
    parser.add_argument("--url", help="measure this plant database (an earlier fill's) instead of filling a new one")
    cli = parser.parse_args()
    print(json.dumps(run(n_runs=cli.runs, sample_share=cli.sample_share, rounds=cli.rounds, requests=cli.requests,
                         url=cli.url), indent=2))
