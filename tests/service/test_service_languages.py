"""The HTML report and the certificate in the language asked for (``?lang=``, else the browser's Accept-Language):
every word from one catalogue per language (issue 26 item 5); the catalogues have the same keys and fields."""

from __future__ import annotations

import string

import httpx
import numpy as np
import pytest
from svc_helpers import ScriptedRunner, results_with_uncertainty, serve
from test_service_certificate import pdf_text

from tcms_daq.analysis import evaluate
from tcms_daq.service import certificate_text, messages
from tcms_daq.service.fonts import cjk_fonts
from tcms_daq.store import open_store

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")


def _fields(template: str) -> set[str]:
    return {name for _, name, _, _ in string.Formatter().parse(template) if name}


def _core_notice(key: str) -> bool:
    """A translation of one of the core's coded warnings or budget source names (their English is the core's
    own text)."""
    return (key.startswith("notice.") and not key.startswith("notice.stage_")) or key.startswith("source.")


@pytest.mark.parametrize("module", [messages, certificate_text])
def test_each_language_has_every_key_with_the_same_fields(module):
    for lang, words in module.CATALOGUES.items():
        assert {k for k in words if not _core_notice(k)} == set(module.EN), lang
        for key, template in words.items():
            if not _core_notice(key):
                assert _fields(template) == _fields(module.EN[key]), (lang, key)


def _core_notices() -> dict[str, set[str] | None]:
    """Every code the core gives a warning or reason (``Notice(code, template, **params)`` in tcms_daq), with the
    names of its params (None when they are passed as a mapping); an f-string code's constant head ends in '*'."""
    import ast
    from pathlib import Path

    import tcms_daq

    found: dict[str, set[str] | None] = {}
    for path in Path(tcms_daq.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "Notice"):
                continue
            names = None if any(k.arg is None for k in node.keywords) else {k.arg for k in node.keywords if k.arg}
            code = node.args[0]
            if isinstance(code, ast.JoinedStr):
                found[str(code.values[0].value) + "*"] = names  # type: ignore[attr-defined]
            for const in ast.walk(code):
                if isinstance(const, ast.Constant) and isinstance(const.value, str) and code is const or (
                        isinstance(code, ast.IfExp) and isinstance(const, ast.Constant)):
                    found[const.value] = names
    return found


def test_every_coded_warning_of_the_core_has_its_chinese_with_its_params():
    core = _core_notices()
    assert {"drift_corrected", "reduced_amplitude", "loop_left_out_gap", "rigidity_unit_mixup"} <= set(core)
    zh = {k.removeprefix("notice."): v for k, v in messages.ZH.items() if k.startswith("notice.") and _core_notice(k)}
    for code, params in core.items():
        translated = [k for k in zh if k.startswith(code[:-1])] if code.endswith("*") else [code] if code in zh else []
        assert translated, f"no Chinese for the core's warning {code}"
        for key in translated:
            if params is not None:
                assert _fields(zh[key]) <= params, (key, _fields(zh[key]) - params)
    for key in zh:
        assert key in core or any(c.endswith("*") and key.startswith(c[:-1]) for c in core), f"{key}: no such code"


def _page_keys() -> set[str]:
    """Every catalogue key the pages name: data-i18n* attributes of the HTML, literal t("…") in the scripts, and the
    turning tests' keys the dashboard makes from a prefix and a name (methods, directions, components, procedure
    steps, result labels)."""
    import re
    from pathlib import Path

    from tcms_daq.procedure.methods import METHODS, TURNING_METHODS
    from tcms_daq.service.method_views import Quantity, quantities
    from tcms_daq.transmission.kinematics import COMPONENTS

    static = Path(messages.__file__).parent / "static"
    keys = {m.group(2) for path in static.glob("*.html")
            for m in re.finditer(r'data-i18n(-placeholder|-title)?="([^"]+)"', path.read_text(encoding="utf-8"))}
    keys |= {m.group(1) for path in static.glob("*.js")
             for m in re.finditer(r'\bt\("([^"]+)"[,)]', path.read_text(encoding="utf-8"))}
    keys |= {f"certificate.method_name_{m}" for m in METHODS} | {f"certificate.figure_{m}" for m in TURNING_METHODS}
    keys |= {f"certificate.direction_{d}" for d in ("forward", "reverse")}
    keys |= {f"certificate.component_{c}" for names in COMPONENTS.values() for c in names}
    keys |= {f"step.{s}" for s in ("pause", "load", "stop", "unload", "done")}
    results = ({"method": "transmission-error"}, {"method": "starting-torque"}, {"method": "efficiency"},
               {"method": "no-load-torque", "speeds_rpm": [500.0]})
    labels: list[Quantity] = [q for r in results for q in quantities(r)]
    return keys | {f"certificate.q_{q.label}" for q in labels} | {"certificate.q_hysteresis_arcsec"}


def test_every_word_the_pages_name_is_in_each_language():
    keys = _page_keys()
    assert {"dash.method", "certificate.method_name_efficiency", "certificate.component_pin_ring", "step.creep",
            "certificate.q_no_load_torque_nm", "dash.te_spectrum_live_over"} <= keys
    for lang, words in messages.CATALOGUES.items():
        certificate_words = certificate_text.CATALOGUES[lang]
        missing = sorted(k for k in keys if k not in words and not (
            k.startswith("certificate.") and k.removeprefix("certificate.") in certificate_words))
        assert not missing, (lang, missing)


def test_the_chinese_terms_of_the_standards():
    zh = messages.catalogue("zh")
    assert zh["res.rigidity"].startswith("扭转刚度") and zh["res.lost_motion"].startswith("空程")
    assert zh["res.backlash"].startswith("背隙") and zh["certificate.q_rigidity_nm_per_arcmin"] == "扭转刚度"
    assert messages.language(None, "zh-CN,zh;q=0.9,en;q=0.8") == "zh"
    assert messages.language("en", "zh-CN") == "en" and messages.language(None, "fr-FR") == "en"


def _stored_run(data_dir) -> str:
    t = np.linspace(0.0, 20.0, 2000)
    torque = 300.0 * np.sin(2 * np.pi * t / 10.0)
    angle = torque / 290.0 * 60.0 + 10.0 * np.sign(np.cos(2 * np.pi * t / 10.0))
    with open_store(None, data_dir) as store:
        store.create_run("run-1", {"reducer": "RV-110E", "serial_number": "SN-7", "max_torque_nm": 300.0,
                                   "user": "olga", "plan": {"id": 1, "name": "incoming", "version": 2}}, CHANNELS)
        store.append_samples("run-1", [{"time_s": t, "torque_nm": torque, "angle_arcsec": angle,
                                        "encoder_arcsec": angle}])
        # with a warning of the core (its English and its code): a record whose angle column is in degrees
        degrees = evaluate(t, torque, angle / 3600.0, rated_torque_nm=300.0).to_dict()
        results = {**results_with_uncertainty(), "warnings": degrees["warnings"], "notices": degrees["notices"]}
        store.set_status("run-1", "completed", results=results)
    return "run-1"


def test_report_and_certificate_in_chinese_and_english(settings_factory):
    settings = settings_factory()
    run_id = _stored_run(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv:
        english = httpx.get(f"{srv.base}/api/tests/{run_id}/report", timeout=60).text
        assert "torsional rigidity / N·m/arcmin" in english and "扭转刚度" not in english
        assert "incoming v2" in english and "olga" in english
        chinese = httpx.get(f"{srv.base}/api/tests/{run_id}/report", params={"lang": "zh"}, timeout=60).text
        assert '<html lang="zh-CN">' in chinese
        for word in ("扭转刚度 / N·m/arcmin", "空程 / arcsec", "背隙 / arcsec", "滞回曲线", "合格判定",
                     "按角秒计不合理地小"):
            assert word in chinese, word
        assert "implausibly small for arcsec" in english and "implausibly small" not in chinese
        by_browser = httpx.get(f"{srv.base}/api/tests/{run_id}/report", timeout=60,
                               headers={"Accept-Language": "zh-CN,zh;q=0.9"}).text
        assert "扭转刚度" in by_browser
        assert httpx.get(f"{srv.base}/api/tests/{run_id}/report", params={"lang": "fr"}).status_code == 422
        if not cjk_fonts():
            pytest.skip("no CJK font installed (bash scripts/setup --test installs fonts-noto-cjk)")
        pdf = httpx.get(f"{srv.base}/api/tests/{run_id}/certificate.pdf", params={"lang": "zh"}, timeout=120)
        assert pdf.status_code == 200, pdf.text
        text = pdf_text(pdf.content)
        for word in ("试验证书", "扭转刚度", "空程", "背隙", "委托方与被测件", "SN-7", "若为度则为"):
            assert word in text, word
        assert "implausibly" not in text
        assert "Test certificate" in pdf_text(httpx.get(f"{srv.base}/api/tests/{run_id}/certificate.pdf",
                                                        timeout=120).content)


def test_a_chinese_certificate_without_a_cjk_font_is_a_clear_503(settings_factory, monkeypatch):
    from tcms_daq.service import fonts

    settings = settings_factory()
    run_id = _stored_run(settings.data_dir)
    monkeypatch.setattr(fonts, "cjk_fonts", lambda: ())
    with serve(settings, runner=ScriptedRunner()) as srv:
        r = httpx.get(f"{srv.base}/api/tests/{run_id}/certificate.pdf", params={"lang": "zh"}, timeout=60)
        assert r.status_code == 503 and "no CJK font installed" in r.json()["detail"]


def test_tcms_certificate_lang_zh(tmp_path):
    import subprocess
    import sys

    if not cjk_fonts():
        pytest.skip("no CJK font installed (bash scripts/setup --test installs fonts-noto-cjk)")
    run_id = _stored_run(tmp_path / "data")
    out = tmp_path / "cert-zh.pdf"
    done = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "certificate", run_id, "--data-dir",
                           str(tmp_path / "data"), "--lang", "zh", "-o", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert "试验证书" in pdf_text(out.read_bytes()) and "扭转刚度" in pdf_text(out.read_bytes())


def test_uncertainty_sources_in_chinese_by_the_cores_own_names():
    from pathlib import Path

    import tcms_daq

    core = "".join(p.read_text(encoding="utf-8") for p in (Path(tcms_daq.__file__).parent / "uncertainty").glob("*.py"))
    for key in messages.ZH:
        if key.startswith("source.") and key not in {k for _, k in messages.SOURCE_PATTERNS}:
            assert f'"{key.removeprefix("source.")}"' in core, f"{key}: the core names no such source"
    assert messages.source_text("interpolation error (72″ period), sine", "zh") == "细分误差（信号周期 72″），正弦分量"
    assert messages.source_text("repeatability (loop-to-loop, n = 3)", "zh") == "重复性（循环间，n = 3）"
    assert messages.source_text("repeatability and noise within the record, pooled (n = 4, 8 re-evaluations with fresh "
                                "noise)", "zh") == "重复性与记录内噪声，合并（n = 4，8 次以新噪声重新评定）"
    assert messages.source_text("torque scale", "zh") == "扭矩标度"
    assert messages.source_text("torque scale", "en") == "torque scale"
    assert messages.source_text("a source of a later version", "zh") == "a source of a later version"
    assert messages.source_text("declared chain: bench config bench-sim.toml", "zh") == \
        "声明的测量链：试验台配置 bench-sim.toml"
    # a turning test's basis (tcms_daq.procedure.method_evaluation), with or without the station's chain
    assert messages.source_text("declared chain: [uncertainty.station] of bench-station.toml", "zh") == \
        "声明的测量链：bench-station.toml 的 [uncertainty.station]"
    assert messages.source_text("declared chain: a declared chain", "zh") == "声明的测量链：a declared chain"
    from tcms_daq.procedure.method_evaluation import NO_STATION_CHAIN
    assert messages.source_text(NO_STATION_CHAIN, "zh") == "仅 A 类（未声明 [uncertainty.station]）"
    assert messages.source_text("type A only (no uncertainty declared in bench.toml)", "zh") == \
        "仅 A 类（bench.toml 中未声明不确定度）"
