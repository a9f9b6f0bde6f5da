"""A turning test's results where people and machines read them (issue 28 item 6): the certificate of each method
(read with pdftotext, its page rendered with pdftoppm), the two-axis record's exports (CSV, MDF4 read back with
asammdf, Parquet, the sidecar), the curves the dashboard draws (GET /api/tests/{id}/curves), and OPC UA (each
method's results as typed 40001-101 results with EngineeringUnits and U, read by an independent asyncua client).
One run of each method on the simulated station (config/bench-station.toml, through the service), stored once for
the module."""

from __future__ import annotations

import asyncio
import io
import json
import shutil
import subprocess
from typing import Any

import numpy as np
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest
from svc_helpers import STATION_METHODS, ScriptedRunner, serve, station_runs
from test_service_certificate import pdf_text

from tcms_daq.analysis.rounding import round_to_uncertainty
from tcms_daq.service.app import ServiceSettings
from tcms_daq.store import open_store

UNIT_ID = {"arcsec": int.from_bytes(b"D62", "big"), "N·m": int.from_bytes(b"NU", "big"),
           "1": int.from_bytes(b"C62", "big")}


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    """The store of one completed run of each turning method (RV-110E): (data dir, {method: record},
    {method: columns})."""
    data_dir = tmp_path_factory.mktemp("station") / "data"
    ids = station_runs(data_dir, serial_number="SN-28-0001", operator="Li Wei", customer="ACME Robotics")
    with open_store(None, data_dir) as store:
        records = {m: store.get_run(run_id) for m, run_id in ids.items()}
        columns = {m: store.read_columns(run_id) for m, run_id in ids.items()}
    return data_dir, records, columns


def _pm(value: float, entry: dict, scale: float = 1.0, unit: str = "") -> str:
    """"v ± U<unit> (k = …)" written out from a result and its uncertainty entry (the certificate's rounding)."""
    v, u = round_to_uncertainty(scale * value, scale * entry["U"])
    return f"{v} ± {u}{unit} (k = {entry['k']:.2f})"


def _coloured(png) -> tuple[int, int]:
    """Pixels of a rendered page in a saturated blue or orange (the directions' curves), and in red (the marks)."""
    from matplotlib.image import imread

    image = imread(png)[..., :3] * 255.0
    saturated = image.max(axis=-1) - image.min(axis=-1) > 60
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    curves = saturated & ((b > r + 40) | ((r > b + 60) & (g > 80)))
    return int(curves.sum()), int((saturated & (r > 150) & (g < 70)).sum())


def _render_page(pdf: bytes, tmp_path, name: str):
    page = tmp_path / name
    subprocess.run(["pdftoppm", "-r", "60", "-f", "1", "-l", "1", "-png", "-singlefile", "-", str(page)], input=pdf,
                   check=True)
    return page.with_suffix(".png")


@pytest.mark.timeout(240)
def test_certificate_of_each_method_has_its_reference_results_rounded_to_u_and_its_figure(station, tmp_path):
    from tcms_daq.service.certificate import render_certificate

    if shutil.which("pdftoppm") is None:
        pytest.skip("no pdftoppm (poppler-utils)")
    _, records, columns = station
    reference = {"transmission-error": ("Transmission error of a precision reducer", "GB/T 35089-2018 §8, transmission"),
                 "starting-torque": ("Starting torque of a precision reducer", "GB/T 35089-2018 §7, starting torque"),
                 "no-load-torque": ("No-load running torque of a precision reducer", "GB/T 35089-2018 §7, no-load"),
                 "efficiency": ("Transmission efficiency of a precision reducer", "GB/T 35089-2018 §7, transmission")}
    for method, record in records.items():
        res = record.results
        unc = res["uncertainty"]
        pdf = render_certificate(record, columns[method])
        text = pdf_text(pdf)
        assert all(words in text for words in reference[method]), method
        assert "Serial number SN-28-0001" in text and "No acceptance limits are stated for this test" in text
        assert "GB/T 35089-2018, torsional rigidity" not in text and "Hysteresis curve" not in text
        if method == "transmission-error":
            for key, label in (("transmission_error_arcsec", "Transmission error (peak-to-peak, the larger direction)"),
                               ("forward_transmission_error_arcsec", "Transmission error, forward"),
                               ("reverse_transmission_error_arcsec", "Transmission error, reverse")):
                assert f"{label} {_pm(res[key], unc[key], unit='″')}" in text, key
            assert "Input speed 2000 rpm" in text and "Output revolutions per direction 1.15" in text
            for line in res["te_orders"]:  # the lines' table: order, component, amplitude ± U
                entry = unc[f"te_order_{line['order']:.4g}_amplitude_arcsec"]
                assert f"{line['order']:.5g} " in text and _pm(line["amplitude_arcsec"], entry) in text, line["order"]
            # each row names the line's component: order, component, amplitude ± U side by side
            table = text[text.index("Harmonic lines of the transmission error"):]
            for order, words in ((39, "pin ring"), (40, "crankshaft / cycloid disc"), (161, "input shaft")):
                line = next(x for x in res["te_orders"] if round(x["order"]) == order)
                entry = unc[f"te_order_{line['order']:.4g}_amplitude_arcsec"]
                row = f"{line['order']:.5g} {words} {_pm(line['amplitude_arcsec'], entry)}"
                assert row in table, (row, table[:600])
        elif method == "starting-torque":
            assert f"Starting torque (the larger direction) {_pm(res['starting_torque_nm'], unc['starting_torque_nm'], unit=' N·m')}" in text
            assert "Breakaways per direction 3" in text
        elif method == "no-load-torque":
            for n in res["speeds_rpm"]:
                key = f"no_load_torque_nm@{n:g}rpm"
                assert f"No-load running torque at {n:g} rpm {_pm(res[key], unc[key], unit=' N·m')}" in text, n
        else:
            for d in ("forward", "reverse"):
                key = f"{d}_efficiency"
                assert f"Efficiency, {d} {_pm(res[key], unc[key], 100.0, ' %')}" in text, d  # in %
        # the figure is drawn on page 1: the directions' blues and oranges, the marks' red (a page without it has no
        # saturated colour at all)
        curves, marks = _coloured(_render_page(pdf, tmp_path, method))
        assert curves > 300, (method, curves)
        if method != "efficiency":
            assert marks > 10, (method, marks)


def test_the_transmission_error_certificate_in_chinese(station):
    from tcms_daq.service.certificate import render_certificate
    from tcms_daq.service.fonts import cjk_fonts

    if not cjk_fonts():
        pytest.skip("no CJK font installed (bash scripts/setup --test installs fonts-noto-cjk)")
    _, records, columns = station
    text = pdf_text(render_certificate(records["transmission-error"], columns["transmission-error"], lang="zh"))
    for word in ("精密减速器传动误差", "GB/T 35089-2018 第 8 章", "传动误差（峰峰值，取较大方向）", "传动误差的谐波分量",
                 "针齿壳", "曲柄轴 / 摆线轮", "输出编码器（1–2 阶）", "本试验未规定验收限值"):
        assert word in text, word
    assert "pin ring" not in text and "Transmission error" not in text


@pytest.fixture(scope="module")
def served(station, tmp_path_factory):
    """The service over the module's store (a scripted bench: nothing runs), for its exports and curves."""
    data_dir, records, _ = station
    settings = ServiceSettings(data_dir=data_dir, api_token="test-token-123")
    with serve(settings, runner=ScriptedRunner()) as server:
        yield server.client(), records


def test_the_two_axis_record_in_csv_and_mdf4_reads_back(served, station):
    from asammdf import MDF

    from tcms_daq.service.exports import PROJECT_TURNING

    c, records = served
    _, _, columns = station
    run_id = records["transmission-error"].id
    stored = columns["transmission-error"]
    names = ["time_s", "torque_nm", "angle_arcsec", "encoder_arcsec", "input_angle_arcsec", "input_torque_nm"]
    body = c.get(f"/api/tests/{run_id}/samples", params={"format": "csv"}).content
    assert body.startswith((",".join(names) + "\n").encode())
    table = pa_csv.read_csv(io.BytesIO(body))
    for name in names:
        np.testing.assert_array_equal(table.column(name).to_numpy(), stored[name], err_msg=name)
    # the two axes are the reducer's: the input turns i = 161 times the output (and the columns are not swapped)
    ratio = np.ptp(table.column("input_angle_arcsec").to_numpy()) / np.ptp(table.column("angle_arcsec").to_numpy())
    assert ratio == pytest.approx(161.0, rel=0.01)
    side = c.get(f"/api/tests/{run_id}/metadata").json()
    assert side["channels"]["input_torque_nm"] == {"unit": "N·m", "description": "input torque (turning the input "
                                                   "forward is positive)"}
    assert side["channels"]["torque_nm"]["description"].startswith("output torque (the loader's")
    assert side["identity"]["method"]["kind"] == "transmission-error"

    mdf = MDF(io.BytesIO(c.get(f"/api/tests/{run_id}/samples", params={"format": "mdf4"}).content))
    try:
        assert mdf.header.project == PROJECT_TURNING
        text = mdf.header.description
        assert "method: transmission-error\n" in text and "input speed 2000 rpm" in text
        res = records["transmission-error"].results
        entry = res["uncertainty"]["transmission_error_arcsec"]
        assert f"transmission error: {_pm(res['transmission_error_arcsec'], entry, unit='″')}" in text
        units = {"torque_nm": "N·m", "angle_arcsec": "arcsec", "input_angle_arcsec": "arcsec", "input_torque_nm": "N·m"}
        for name, unit in units.items():
            signal = mdf.get(name)
            assert signal.unit == unit, name
            np.testing.assert_array_equal(signal.samples, stored[name], err_msg=name)
            np.testing.assert_allclose(signal.timestamps, stored["time_s"] - stored["time_s"][0], atol=1e-9)
        assert mdf.get("input_angle_arcsec").comment.startswith("input angle (input encoder")
        assert mdf.get("angle_arcsec").comment.startswith("output angle, compensated")
    finally:
        mdf.close()
    schema = pq.read_table(io.BytesIO(c.get(f"/api/tests/{run_id}/samples", params={"format": "parquet"}).content)
                           ).schema
    assert schema.field("input_angle_arcsec").metadata[b"unit"] == b"arcsec"
    doc = c.get(f"/api/tests/{run_id}/samples", params={"format": "json"}).json()
    assert doc["columns"] == names and doc["units"]["input_torque_nm"] == "N·m"
    np.testing.assert_array_equal(doc["data"]["input_angle_arcsec"], stored["input_angle_arcsec"])


def test_the_curves_the_dashboard_draws(served, station):
    c, records = served
    _, _, columns = station
    te = c.get(f"/api/tests/{records['transmission-error'].id}/curves").json()
    assert te["method"] == "transmission-error"
    assert [q["key"] for q in te["quantities"]] == ["transmission_error_arcsec", "forward_transmission_error_arcsec",
                                                    "reverse_transmission_error_arcsec"]
    named = {round(line["order"]): line["component"] for line in te["te_lines"]}
    assert named[39] == "pin_ring" and named[161] == "input" and named[1] == "output"
    for d in ("forward", "reverse"):
        curve = te["te_curve"][d]
        assert len(curve["output_angle_deg"]) == len(curve["te_arcsec"]) > 300
        assert np.ptp(curve["te_fit_arcsec"]) > 10.0  # the RV-110E's lines: not a flat curve
    # each starting-torque ramp is cut around its own breakaway: at the onset the input torque is the starting
    # torque, before it the input stands, after it it has turned
    start = c.get(f"/api/tests/{records['starting-torque'].id}/curves").json()
    listed = records["starting-torque"].results["ramps"]  # 3 per direction (fewer if a ramp could not be fitted)
    assert len(start["ramps"]) == len(listed) and {r["direction"] for r in start["ramps"]} == {"forward", "reverse"}
    for ramp in start["ramps"]:
        t = np.asarray(ramp["time_from_onset_s"])
        torque, angle = np.asarray(ramp["input_torque_nm"]), np.asarray(ramp["input_angle_arcsec"])
        sign = -1.0 if ramp["direction"] == "reverse" else 1.0
        at = int(np.flatnonzero(t <= 0.0)[-1])  # the last sample before the breakaway (the torque drops after it)
        assert abs(torque[at] - sign * ramp["torque_nm"]) < 0.01, ramp["onset_s"]
        assert np.ptp(angle[(t > -1.0) & (t < -0.05)]) < 5.0 and abs(angle[-1] - angle[at]) > 100.0
        assert t[0] < -3.0 and abs(torque[0]) < 0.1  # the whole ramp, from where the torque stood near zero
    noload = c.get(f"/api/tests/{records['no-load-torque'].id}/curves").json()
    res = records["no-load-torque"].results
    assert [s["speed_rpm"] for s in noload["speeds"]] == res["speeds_rpm"]
    for s in noload["speeds"]:
        half = (s["forward"]["value"] + s["reverse"]["value"]) / 2.0  # magnitudes: the zero cancels
        assert s["no_load"]["value"] == pytest.approx(half, abs=1e-4) and s["no_load"]["U"] > 0
    eff = c.get(f"/api/tests/{records['efficiency'].id}/curves").json()
    for d in eff["directions"]:
        assert np.mean(d["block_efficiencies"]) == pytest.approx(d["value"], abs=2e-3) and d["U"] > 0


@pytest.mark.timeout(120)
def test_an_independent_opcua_client_reads_each_method_as_typed_results(station):
    from asyncua import Client, ua

    from tcms_daq.config.models import OpcUaSection
    from tcms_daq.service.opcua import OpcUaBridge

    data_dir, records, _ = station
    bench_id = records["efficiency"].bench_id

    async def read(endpoint: str) -> tuple[dict, dict]:
        async with Client(endpoint, timeout=20) as client:
            await client.load_data_type_definitions()
            result_ns = await client.get_namespace_index("http://opcfoundation.org/UA/Machinery/Result/")
            machinery = await client.get_namespace_index("http://opcfoundation.org/UA/Machinery/")
            bench_ns = await client.get_namespace_index(f"urn:tcms-daq:bench:{bench_id}")
            bench = await client.nodes.objects.get_child([f"{machinery}:Machines", f"{bench_ns}:{bench_id}"])
            manager = await bench.get_child(f"{result_ns}:ResultManagement")
            by_method = {}
            for method, record in records.items():
                _, result, error = await manager.call_method(
                    f"{result_ns}:GetResultById", ua.Variant(record.id, ua.VariantType.String),
                    ua.Variant(0, ua.VariantType.Int32))
                assert error == 0 and result.ResultMetaData.InternalRecipeId == method
                assert json.loads(result.ResultContent[0].Value)["full_results"]["method"] == method
                by_method[method] = {q.Value.Name: q.Value for q in result.ResultContent[1:]}
            latest = await manager.get_child([f"{result_ns}:Results", f"{bench_ns}:LatestResult"])
            shown = {"method": await (await latest.get_child(f"{bench_ns}:Method")).read_value(),
                     "rigidity": await (await latest.get_child(f"{bench_ns}:TorsionalRigidity")).read_value()}
            for node in await (await latest.get_child(f"{bench_ns}:Quantities")).get_children():
                name = (await node.read_browse_name()).Name
                shown[name] = (await node.read_value(),
                               await (await node.get_child(f"{bench_ns}:ExpandedUncertainty")).read_value(),
                               (await (await node.get_child("0:EngineeringUnits")).read_value()).UnitId)
            return by_method, shown

    async def replaced(bridge: OpcUaBridge, run_id: str) -> tuple[Any, set[str]]:
        """A client subscribed to model changes while a new result replaces LatestResult/Quantities."""
        changes: asyncio.Queue = asyncio.Queue()

        class Handler:
            def event_notification(self, event: Any) -> None:
                changes.put_nowait(event)

        async with Client(bridge.endpoint, timeout=20) as client:
            subscription = await client.create_subscription(20, Handler())
            await subscription.subscribe_events(client.nodes.server,
                                                client.get_node(ua.NodeId(ua.ObjectIds.GeneralModelChangeEventType)))
            bridge.on_event({"type": "test_state", "status": "completed", "id": run_id})
            event = await asyncio.wait_for(changes.get(), 20)
            folder = client.get_node(event.Changes[0].Affected)
            return event, {(await n.read_browse_name()).Name for n in await folder.get_children()}

    with open_store(None, data_dir) as store:
        bridge = OpcUaBridge(store, bench_id, "simulated station", 0,
                             config=OpcUaSection(anonymous=True, security_modes=["None"]))
        bridge.start()
        try:
            by_method, latest = asyncio.run(read(bridge.endpoint))
            change, browsed = asyncio.run(replaced(bridge, records["transmission-error"].id))
        finally:
            bridge.stop()
    expected = {
        "transmission-error": {"TransmissionError": ("transmission_error_arcsec", "arcsec"),
                               "TransmissionErrorReverse": ("reverse_transmission_error_arcsec", "arcsec"),
                               "TeOrder_39_Amplitude": ("te_order_39_amplitude_arcsec", "arcsec")},
        "starting-torque": {"StartingTorqueForward": ("forward_starting_torque_nm", "N·m")},
        "no-load-torque": {f"NoLoadTorque_{n:g}rpm": (f"no_load_torque_nm@{n:g}rpm", "N·m")
                           for n in records["no-load-torque"].results["speeds_rpm"]},
        "efficiency": {"EfficiencyForward": ("forward_efficiency", "1"), "EfficiencyReverse": ("reverse_efficiency", "1")},
    }
    assert set(by_method) == set(STATION_METHODS)
    for method, quantities in expected.items():
        res = records[method].results
        for name, (key, unit) in quantities.items():
            q, entry = by_method[method][name], res["uncertainty"][key]
            value = res[key] if key in res else next(line["amplitude_arcsec"] for line in res["te_orders"]
                                                     if round(line["order"]) == 39)
            assert (q.Value, q.ExpandedUncertainty, q.CoverageFactor) == pytest.approx((value, entry["U"], entry["k"]))
            assert q.EngineeringUnits.UnitId == UNIT_ID[unit], name
            assert q.EngineeringUnits.NamespaceUri == "http://www.opcfoundation.org/UA/units/un/cefact"
    assert "pin_ring" in by_method["transmission-error"]["TeOrder_39_Amplitude"].Text
    # LatestResult: the newest run's (the efficiency's) quantities as variables; the stiffness ones NaN
    assert latest["method"] == "efficiency" and np.isnan(latest["rigidity"])
    # a new result remakes the quantities, and a client subscribed to model changes is told where to browse again
    assert change.Changes[0].Verb == 4 | 8  # ReferenceAdded | ReferenceDeleted
    assert "TransmissionError" in browsed and "EfficiencyForward" not in browsed
    res = records["efficiency"].results
    assert latest["EfficiencyForward"] == pytest.approx((res["forward_efficiency"],
                                                         res["uncertainty"]["forward_efficiency"]["U"], UNIT_ID["1"]))
