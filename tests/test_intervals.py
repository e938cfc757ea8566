"""The split-conformal intervals of the identified frequency and damping ratio (lagsplat.evaluate.intervals)."""

import json
import math

import numpy as np
import pytest

from lagsplat.evaluate.intervals import FLOOR_FREQ, FLOOR_ZETA, conformal_k, intervals, load_calibration


def _entry(v):
    return {"value": v}


def test_conformal_k_is_the_rank_ceil_n_plus_1_times_level():
    scores = list(range(1, 21))  # 20 scores: rank ceil(21 * 0.9) = 19
    assert conformal_k(scores, 0.9) == 19
    assert conformal_k(scores[:8], 0.9) == math.inf  # ceil(9 * 0.9) = 9 > 8: no finite constant has the guarantee
    assert conformal_k([1.0, float("nan"), 2.0] + list(range(3, 12)), 0.9) == 11  # non-finite scores are left out


def test_conformal_intervals_cover_exchangeable_clips_at_the_nominal_rate():
    # clips whose error against the truth is their own disagreement times a heavy-tailed factor: calibrated on 15,
    # the interval holds the truth of a new clip at least 90 % of the time (averaged over many draws), and the
    # naive interval (k = 1, the disagreement alone) falls well short
    rng = np.random.default_rng(0)
    hits, naive = [], []
    for _ in range(4000):
        s = rng.uniform(0.002, 0.03, 16)
        err = s * np.abs(rng.standard_t(3, 16)) * 1.5
        k = conformal_k(list(err[:15] / s[:15]), 0.9)
        hits.append(err[15] <= k * s[15])
        naive.append(err[15] <= s[15])
    assert 0.9 <= np.mean(hits) <= 0.97
    assert np.mean(naive) < 0.7


def test_intervals_scale_with_the_clips_own_disagreement():
    cal = {"k_freq": 2.0, "k_zeta": 3.0, "clips": ["a", "b"], "commit": "abc"}
    m = {"f_sim_hz": _entry(1.0), "eps_freq": _entry(0.01), "zeta_sim": _entry(0.02), "zeta_enc": _entry(0.025)}
    iv = intervals(m, cal)
    lo, hi = iv["f_sim_hz_interval"]["value"]
    assert lo == pytest.approx(1 - 2 * (0.01 + FLOOR_FREQ)) and hi == pytest.approx(1 + 2 * (0.01 + FLOOR_FREQ))
    zlo, zhi = iv["zeta_sim_interval"]["value"]
    assert zlo == pytest.approx(0.02 - 3 * (0.005 + FLOOR_ZETA)) and zhi == pytest.approx(0.02 + 3 * (0.005 + FLOOR_ZETA))
    # a clip identified on all its frames: its in-sample disagreement; without a damping ratio: no damping interval
    m2 = {"f_sim_hz": _entry(0.5), "eps_freq": _entry(None), "eps_freq_in_sample": _entry(0.04), "zeta_sim": _entry(None)}
    iv2 = intervals(m2, cal)
    assert iv2["f_sim_hz_interval"]["value"][1] == pytest.approx(0.5 * (1 + 2 * (0.04 + FLOOR_FREQ)))
    assert iv2["zeta_sim_interval"]["value"] is None
    none = intervals(m, None)
    assert none["f_sim_hz_interval"]["value"] is None and "no calibration" in none["f_sim_hz_interval"]["definition"]


def test_a_calibration_file_is_read_and_a_wrong_one_named(tmp_path):
    assert load_calibration(tmp_path / "absent.json") is None
    good = tmp_path / "cal.json"
    good.write_text(json.dumps({"k_freq": 1.5, "k_zeta": 2.5}))
    assert load_calibration(good)["k_freq"] == 1.5
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"k": 1}))
    with pytest.raises(ValueError, match="bad.json"):
        load_calibration(bad)


def test_the_report_leads_with_the_identified_quantities_and_their_intervals():
    from lagsplat.diagnose.quantities import Z90, identified_quantities, quantities_section

    mj = {"metrics": {"f_sim_hz": _entry(0.79), "f_sim_hz_interval": _entry([0.77, 0.81]), "zeta_sim": _entry(0.01),
                      "zeta_sim_interval": {"value": None, "definition": "no interval: the package has no calibration"},
                      "f_modes_hz": _entry([0.83]), "zeta_modes": _entry([0.0095])}}  # fmt: skip
    diag = {"effects": [{"effect": "coulomb", "coefficients": {"mu": {"value": 4.0, "se": 0.5}}},
                        {"effect": "drift", "coefficients": {"dk_dt": {"value": 1.0, "se": 0.1}}}]}  # fmt: skip
    rows = identified_quantities(mj, diag, "coulomb")
    by = {r["quantity"]: r for r in rows}
    assert by["natural frequency (free rollout)"]["interval"] == [0.77, 0.81]
    assert by["damping ratio (free rollout)"]["interval"] is None and "no calibration" in by["damping ratio (free rollout)"]["method"]
    assert by["coulomb: mu"]["interval"] == pytest.approx([4.0 - Z90 * 0.5, 4.0 + Z90 * 0.5])
    assert "drift: dk_dt" not in by  # only the named effect's coefficients
    text = "\n".join(quantities_section({"identified": rows}))
    assert "## Identified quantities" in text and "0.77 to 0.81" in text
    assert quantities_section({"identified": []}) == []
