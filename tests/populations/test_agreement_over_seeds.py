"""The per-seed / pooled agreement index script counts each check over the seeds' targets, as the report's index."""

from pathlib import Path

import pytest
from population_testdata import load_script

HEADER = "target,role,statistic,same_direction,within,sd_ratio,same_verdict,agrees\n"


def _load():
    return load_script("agreement_over_seeds")


def _report(tmp_path: Path, name: str, rows: list[str]) -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / "agreement.csv").write_text(HEADER + "".join(r + "\n" for r in rows))
    return d


def test_pooled_counts_add_the_seeds_and_a_spread_is_not_a_band_check(tmp_path, capsys):
    mod = _load()
    # seed A: the verdict missed, the mean within its band; seed B: the verdict reproduced, the mean outside.
    a = _report(tmp_path, "a", ["m,fit,mean,True,True,,,True", "s,validation,sd,,True,0.8,,True",
                                "v,validation,verdict,,,,False,False"])
    b = _report(tmp_path, "b", ["m,fit,mean,True,False,,,False", "s,validation,sd,,False,1.7,,False",
                                "v,validation,verdict,,,,True,True"])
    assert mod.main([str(a), str(b)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[1:] == ["agree", "2/3", "directions", "1/1", "verdicts", "0/1", "within", "band", "1/1"]
    assert out[2].startswith("pooled over 2 seeds")
    assert out[2].split()[4:] == ["agree", "3/6", "directions", "2/2", "verdicts", "1/2", "within", "band", "1/2"]


def test_a_folder_without_its_table_is_one_error_line(tmp_path):
    with pytest.raises(SystemExit, match="agreement.csv not found"):
        _load().main([str(tmp_path)])
