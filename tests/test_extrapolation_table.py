"""The extrapolation table (lagsplat.report.tables.extrapolation_table, paper Table 3 layout)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from lagsplat.report.tables import extrapolation_table


def _record(path, title, left_node):
    m = {"psnr_mean": 30.0, "psnr_first": 32.0, "psnr_last": 28.0, "psnr_ae_floor_mean": 33.0, "freq_error": 0.012, "dissipation_error": 0.29,
         "amplitude_left": 0.0, "long_s": 1000.0, "f_real_hz": 0.8, "f_model_hz": 0.81, "rate_real_per_s": 0.2, "rate_model_per_s": 0.14}  # fmt: skip
    rec = {"title": title, "names": {"lagsplat": "LaGSplat", "neural_ode": "latent neural ODE"},
           "models": {"lagsplat": m, "neural_ode": {**m, "amplitude_left": left_node, "psnr_mean": None}}}  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec))
    return path


def test_the_table_has_a_column_per_model_and_system(tmp_path) -> None:
    ins = [_record(tmp_path / "a" / "extrapolation.json", "Toy", 0.53), _record(tmp_path / "b" / "extrapolation.json", "Cart", 0.8)]
    tex, csv, md = extrapolation_table(ins, tmp_path / "tables" / "extrapolation.tex")
    t = tex.read_text()
    assert "\\multicolumn{2}{c}{Toy} & \\multicolumn{2}{c}{Cart}" in t and "LaGSplat & latent neural ODE & LaGSplat" in t
    assert "Amplitude left after $1000$\\,s (\\%) & $0.00$ & $53.00$ & $0.00$ & $80.00$ \\\\" in t
    assert "Mean on held out frames & $30.00$ & -- &" in t  # a number not measured reads --
    df = pd.read_csv(csv)
    assert list(df["model"]) == ["LaGSplat", "latent neural ODE"] * 2 and df["freq_error"].iloc[0] == pytest.approx(1.2)
    assert "| Amplitude left after the long extrapolation (%) | 0.00 | 53.00 | 0.00 | 80.00 |" in md.read_text()
    with pytest.raises(FileNotFoundError, match="run the extrapolation stage"):
        extrapolation_table([tmp_path / "missing" / "extrapolation.json"], tmp_path / "t.tex")
