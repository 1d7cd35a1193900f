"""The README's results table is the one results/table.yaml and the results files it names make."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from report import readme_table
from report.readme_table import (
    TableError,
    build_parity,
    build_rows,
    millimetres,
    render,
    render_parity,
    replace_in,
    share,
    spread,
)

ROOT = Path(__file__).resolve().parents[2]


def test_the_readme_table_is_the_generated_one() -> None:
    """Any edit of a row by hand, or of a results.json a row reads, without `python -m report.readme_table --write`
    fails here."""
    table = render(build_rows(ROOT / "results" / "table.yaml", ROOT / "results"))
    assert table in (ROOT / "README.md").read_text()
    parity = build_parity(ROOT / "results" / "table.yaml", ROOT / "results")
    if parity is not None:
        assert render_parity(parity) in (ROOT / "README.md").read_text()


def test_figures_by_hand() -> None:
    assert millimetres(185.04) == "185" and millimetres(2073.0) == "2,073"
    assert spread([202.6, 167.4]) == "185 ± 25"  # mean 185.0, sample std 24.89
    assert spread([48.6]) == "49"
    assert share(1.0) == "1.0" and share(0.0) == "0" and share(0.9375) == "0.94" and share(0.5) == "0.50"


def _results(folder: Path, runs: dict[str, dict[str, float]]) -> None:
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps({"runs": [{"label": k, "overall": v} for k, v in runs.items()]}))


def test_a_row_is_the_mean_and_sample_std_of_its_runs(tmp_path: Path) -> None:
    figures = {"a": {"mpjpe_g": 100.0, "mpjpe_l": 20.0, "survival": 1.0, "success": 0.5},
               "b": {"mpjpe_g": 120.0, "mpjpe_l": 30.0, "survival": 0.5, "success": 0.5},
               "c": {"mpjpe_g": 9999.0, "mpjpe_l": 999.0, "survival": 0.0, "success": 0.0}}  # fmt: skip
    _results(tmp_path / "f", figures)
    (tmp_path / "table.yaml").write_text(
        "rows:\n  - {method: M, motions: walk, folder: f, runs: [a, b], minutes: 30, machine: box}\n")
    row = build_rows(tmp_path / "table.yaml", tmp_path)[0].markdown()
    # run c is in the file but not in the row; mean 110 ± 14.14, 25 ± 7.07, survival 0.75, success 0.5
    assert row == "| M | walk | 110 ± 14 | 25 ± 7 | 0.75 | 0.50 | 30 | box | 2 | [f](results/f/) |"


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("{method: M, motions: w, folder: f, runs: [zz], minutes: 1, machine: m}", "zz not in"),
        ("{method: M, motions: w, folder: nowhere, runs: [a], minutes: 1, machine: m}", "not a compare-trackers"),
        ("{method: M, motions: w, minutes: 1, machine: m}", "needs figures"),
        ("{method: M, motions: w, minutes: 1, machine: m, figures: {mpjpe_g: '1', mpjpe_l: '1', survival: '1', "
         "success: '1', seeds: '1'}, source: gone.txt}", "source gone.txt not found"),
        ("{method: M, motions: w, minutes: 1, machine: m, colour: red}", "unknown keys colour"),
        ("{method: M, minutes: 1, machine: m}", "needs method, motions"),
    ],
)
def test_bad_manifest_rows_are_refused_by_name(tmp_path: Path, row: str, message: str) -> None:
    _results(tmp_path / "f", {"a": {"mpjpe_g": 1.0, "mpjpe_l": 1.0, "survival": 1.0, "success": 1.0}})
    (tmp_path / "table.yaml").write_text(f"rows:\n  - {row}\n")
    with pytest.raises(TableError, match=message):
        build_rows(tmp_path / "table.yaml", tmp_path)


def test_write_replaces_only_the_part_between_the_markers(tmp_path: Path) -> None:
    _results(tmp_path / "f", {"a": {"mpjpe_g": 50.0, "mpjpe_l": 10.0, "survival": 1.0, "success": 1.0}})
    (tmp_path / "table.yaml").write_text(
        "rows:\n  - {method: M, motions: walk, folder: f, runs: [a], minutes: 30, machine: box}\n")
    readme = tmp_path / "README.md"
    readme.write_text(f"# title\n\nbefore\n{readme_table.BEGIN}\n| old |\n{readme_table.END}\nafter\n")
    readme_table.main(["--write", "--manifest", str(tmp_path / "table.yaml"), "--readme", str(readme)])
    text = readme.read_text()
    assert text.startswith("# title\n\nbefore\n") and text.endswith("\nafter\n") and "| old |" not in text
    assert "| M | walk | 50 | 10 | 1.0 | 1.0 | 30 | box | 1 | [f](results/f/) |" in text
    with pytest.raises(TableError, match="markers"):
        replace_in("no markers here", "x")


def _pair(a: str, b: str, target: float, hits: list[tuple[float, float] | None]) -> dict:
    """A parity block's pair as report.tables.parity writes it: per seed (sample ratio, time ratio) or None."""
    runs = [{"label": f"{a}-{i}", "seed": i, "samples": None if h is None else 1, "seconds": None,
             "sample_ratio": None if h is None else h[0], "time_ratio": None if h is None else h[1]}
            for i, h in enumerate(hits)]  # fmt: skip
    return {"method": a, "target_method": b, "target": target, "target_samples": 1.0, "target_seconds": 1.0,
            "runs": runs}  # fmt: skip


def test_parity_rows_by_hand(tmp_path: Path) -> None:
    """st reaches ppo's 67.4 mm in 2 of 3 seeds, at mean 0.05x (0.04, 0.06) of the samples and 0.60x (0.5, 0.7) of
    the minutes; ppo never reaches st's 31.2."""
    folder = tmp_path / "suite"
    folder.mkdir()
    pairs = [_pair("st", "ppo", 67.4, [(0.04, 0.5), None, (0.06, 0.7)]), _pair("ppo", "st", 31.2, [None, None, None])]
    (folder / "results.json").write_text(json.dumps({"runs": [], "parity": pairs}))
    (tmp_path / "table.yaml").write_text("rows: []\nparity:\n  - {motions: walk, folder: suite, methods: [st, ppo], "
                                         "names: [ST, PPO], minutes: 30, machine: box}\n")  # fmt: skip
    header, rows = build_parity(tmp_path / "table.yaml", tmp_path)
    assert header[0] == ("| motions | ST reaches PPO's final MPJPE-g | PPO reaches ST's final MPJPE-g | minutes | "
                         "machine | results |")  # fmt: skip
    assert rows == ["| walk | PPO's 67 mm: 2 of 3 seeds, at 0.05x the samples and 0.60x the minutes | ST's 31 mm: "
                    "never (PPO: 0 of 3 seeds) | 30 | box | [suite](results/suite/) |"]  # fmt: skip
    (tmp_path / "table.yaml").write_text("rows: []\nparity:\n  - {motions: walk, folder: suite, methods: [st, amp], "
                                         "names: [ST, AMP], minutes: 30, machine: box}\n")  # fmt: skip
    with pytest.raises(TableError, match="no pair st / amp"):
        build_parity(tmp_path / "table.yaml", tmp_path)
    (tmp_path / "table.yaml").write_text("rows: []\n")
    assert build_parity(tmp_path / "table.yaml", tmp_path) is None


def test_write_replaces_both_tables(tmp_path: Path) -> None:
    folder = tmp_path / "f"
    _results(folder, {"a": {"mpjpe_g": 50.0, "mpjpe_l": 10.0, "survival": 1.0, "success": 1.0}})
    pairs = [_pair("st", "ppo", 67.4, [(0.5, 0.5)]), _pair("ppo", "st", 50.0, [None])]
    (folder / "results.json").write_text(json.dumps({"runs": [{"label": "a", "overall": {
        "mpjpe_g": 50.0, "mpjpe_l": 10.0, "survival": 1.0, "success": 1.0}}], "parity": pairs}))
    (tmp_path / "table.yaml").write_text(
        "rows:\n  - {method: M, motions: walk, folder: f, runs: [a], minutes: 30, machine: box}\n"
        "parity:\n  - {motions: walk, folder: f, methods: [st, ppo], names: [ST, PPO], minutes: 30, machine: box}\n")
    readme = tmp_path / "README.md"
    readme.write_text(f"{readme_table.BEGIN}\n| old |\n{readme_table.END}\nmiddle\n"
                      f"{readme_table.PARITY_BEGIN}\n| old parity |\n{readme_table.END}\nafter\n")  # fmt: skip
    readme_table.main(["--write", "--manifest", str(tmp_path / "table.yaml"), "--readme", str(readme)])
    text = readme.read_text()
    assert "| old" not in text and "\nmiddle\n" in text and text.endswith("\nafter\n")
    assert "| walk | PPO's 67 mm: 1 of 1 seeds, at 0.50x the samples and 0.50x the minutes |" in text
    assert text.index("| M | walk |") < text.index("middle") < text.index("PPO's 67 mm")
