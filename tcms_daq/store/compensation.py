"""The bench's compensation versions in its run store: the one place that checks, keeps, lists and rolls back a
compensator, and turns the bench model's measuring-chain effects into one. The service's routes
(``/api/compensation``) and the command line (``tcms compensation``) both call :class:`CompensationVersions`.

A version is the compensator TOML as applied (normalised by :meth:`Compensator.to_toml`), its note, and for a
rollback the version it restores. The newest version is the one in use: a running service applies an upload at
once (``apply``); an upload made from the command line takes effect when the bench's service next starts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from tcms_daq.compensation import Compensator
from tcms_daq.compensation.plausibility import plausibility_problems
from tcms_daq.config.models import CompensationChecks
from tcms_daq.errors import TcmsError
from tcms_daq.store.base import BenchModelVersion, CompensationVersion, Store

NOTE_MAX_CHARS = 200


class CompensationRejected(TcmsError):
    """A compensator that does not load or is not plausible (one line; the service answers 422)."""


class UnknownVersion(TcmsError):
    """No compensation version of that number (the service answers 404)."""


def checked_compensator(text: str, source: str = "body", checks: CompensationChecks | None = None) -> Compensator:
    """The compensator of ``text`` (compensator TOML or geometry TOML) when it loads and is plausible (within the
    bands of ``checks``, the bench config's ``[compensation_checks]``; default bands when None);
    CompensationRejected naming the first problem otherwise."""
    try:
        compensator = Compensator.loads(text, source=source)
    except (TcmsError, RecursionError, TypeError, ValueError) as exc:
        raise CompensationRejected(
            f"compensation: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    problems = plausibility_problems(compensator, checks if checks is not None else CompensationChecks())
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise CompensationRejected(f"compensation not plausible: {problems[0]}{more}")
    return compensator


#: applies a checked compensator TOML to a running bench and returns the TOML as applied
Apply = Callable[[str], str]


@dataclass(frozen=True)
class FromModel:
    """What :meth:`CompensationVersions.from_model` did: the compensation version it kept and the bench model
    version that no longer holds the moved effects."""

    compensation: CompensationVersion
    bench_model: BenchModelVersion


@dataclass(frozen=True)
class CompensationVersions:
    """The compensation versions of the bench a store is opened for; ``checks``: the bench config's
    ``[compensation_checks]`` an upload is held to (a running service's bench applies its own)."""

    store: Store
    checks: CompensationChecks | None = None

    def history(self, limit: int = 100) -> list[CompensationVersion]:
        """The versions, newest (the one in use) first."""
        return self.store.compensation_history(limit)

    def show(self, version: int | None = None) -> tuple[CompensationVersion, str]:
        """(version, TOML) of ``version`` (None: the one in use); UnknownVersion when there is none."""
        found = self.store.compensation(version)
        if found is None:
            raise UnknownVersion("no compensation version yet" if version is None
                                 else f"no compensation version {version}")
        return found

    def upload(self, text: str, note: str = "", *, rollback_of: int | None = None, apply: Apply | None = None,
               source: str = "body") -> CompensationVersion:
        """Check ``text`` (from ``source``) and keep it as the next version with ``note`` (at most NOTE_MAX_CHARS).
        ``apply``: a running bench takes it first (its TOML as applied is kept). CompensationRejected when it is
        not usable."""
        if len(note) > NOTE_MAX_CHARS:
            raise CompensationRejected(f"note: at most {NOTE_MAX_CHARS} characters, got {len(note)}")
        applied = apply(text) if apply is not None else checked_compensator(text, source, self.checks).to_toml()
        return self.store.add_compensation(applied, note, rollback_of)

    def rollback(self, version: int, *, apply: Apply | None = None) -> CompensationVersion:
        """Use ``version`` again, kept as a new version that names it; UnknownVersion when there is none."""
        _, text = self.show(version)
        return self.upload(text, f"rollback to version {version}", rollback_of=version, apply=apply)

    def from_model(self, in_use_toml: str | None = None, *, apply: Apply | None = None) -> FromModel:
        """The bench model's measuring-chain effects (scale, torsion) added to the compensator in use
        (``in_use_toml``, default the newest version's, else the identity), kept as a new version; the bench
        model keeps only the effects a compensator term cannot take (a new bench model version), so they are not
        corrected twice. CompensationRejected when the bench model has no such effect."""
        from tcms_daq.discrepancy.to_compensation import compensator_terms
        from tcms_daq.store.discrepancy import bench_model

        model_version, model = bench_model(self.store)
        terms, left = compensator_terms(model)
        if not terms:
            raise CompensationRejected(
                f"bench model version {model_version} has no measuring-chain effect a compensator term can take "
                f"(left in the model: {', '.join(left) or 'nothing'})")
        if in_use_toml is None:
            latest = self.store.compensation()
            in_use_toml = latest[1] if latest is not None else Compensator.identity().to_toml()
        current = Compensator.loads(in_use_toml, "the compensation in use")
        note = (f"added {', '.join(t.type_name for t in terms)} from bench model version {model_version}"
                + (f"; left in the model: {', '.join(left)}" if left else ""))
        version = self.upload(current.with_terms(*terms).to_toml(), note[:NOTE_MAX_CHARS], apply=apply)
        kept = replace(model, terms=[t for t in model.terms if t.name in left])
        moved = sorted(set(t.name for t in model.terms) - set(left))
        bench = self.store.add_bench_model(kept.to_toml(),
                                           f"moved {', '.join(moved)} to compensation version {version.version}")
        return FromModel(version, bench)
