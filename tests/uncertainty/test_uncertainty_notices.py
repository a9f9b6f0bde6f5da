"""The evaluation's warnings carry stable codes with their formatted params (issue 26 item 2): the English text
is what it was, the results document keeps ``notices`` beside ``warnings`` one to one, and the pages' catalogue
turns them into Chinese with the same numbers. Records from tests/uncertainty/physics.py."""

from __future__ import annotations

import copy
import json

import numpy as np

from tcms_daq.analysis import evaluate
from tcms_daq.analysis.notices import Notice, notices_in, prepend_warnings
from tcms_daq.service.messages import notice_text, warnings_text

from .physics import Chain, Reducer, measure, triangle, twist_arcsec


def _drifted():
    return measure(Reducer(), Chain(0.0, 0.0, 0.0, 0.0, 0.0), np.random.default_rng(0), rate_nm_per_s=250.0,
                   sample_rate_hz=200.0, drift_arcsec_per_s=0.05)


def test_a_drift_warning_has_its_code_and_its_chinese_with_the_same_numbers():
    ev = evaluate(*_drifted(), rated_torque_nm=1000.0)
    (w,) = [w for w in ev.warnings if "does not close" in w]
    assert isinstance(w, Notice) and w.code == "drift_corrected" and w.params["rate"] == "+0.0497"
    doc = json.loads(json.dumps(ev.to_dict()))  # as the store keeps it
    assert [n["text"] for n in doc["notices"]] == doc["warnings"]
    (n,) = [n for n in doc["notices"] if n["code"] == "drift_corrected"]
    zh = notice_text(n, "zh")
    assert zh.startswith("循环不闭合") and "+0.0497″/s" in zh and n["params"]["corrected"] + "″" in zh
    assert notice_text(n, "en") == w  # English is the core's own text
    assert copy.deepcopy(w).code == "drift_corrected"  # dataclasses.asdict copies it


def test_a_reduced_amplitude_in_chinese_and_old_results_without_codes():
    time_s, torque = triangle(1000.0, 4, 250.0, 200.0)
    tips = np.flatnonzero(np.abs(np.diff(np.sign(np.diff(torque)))) > 0)
    torque = np.where(np.abs(time_s - time_s[tips[4]]) < 0.8 + 150.0 / 250.0, np.clip(torque, -850.0, None), torque)
    doc = evaluate(time_s, torque, twist_arcsec(torque, Reducer()), rated_torque_nm=1000.0).to_dict()
    (zh,) = [w for w in warnings_text(doc, "zh") if w.startswith("幅值不足")]
    assert "-850 N·m" in zh and "85%" in zh
    # a gap warning put before them keeps the notices in step; results of before the codes show their English
    prepend_warnings(doc, [Notice("loop_left_out_gap", "loop {loop} left out, not evaluated across a gap: {gaps}",
                                  loop="2", gaps="torque 0.3 s")])
    assert [n["text"] for n in notices_in(doc)] == doc["warnings"]
    assert warnings_text(doc, "zh")[0] == "第 2 个循环含数据间隙，未参与评定：torque 0.3 s"
    old = {"warnings": ["something the core said in English"]}
    assert warnings_text(old, "zh") == ["something the core said in English"]
