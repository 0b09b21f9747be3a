"""``bench.report.write_section``: a benchmark rewrites its own section of PERFORMANCE.md, nothing else."""

from __future__ import annotations

from pathlib import Path

from bench.report import write_section

DOC = """# Performance

Intro.

<!-- bench:epoch -->
## Epoch latency
old epoch numbers
<!-- /bench:epoch -->

## Notes written by hand
They explain the epoch numbers.

<!-- bench:dro -->
## DRO
dro numbers
<!-- /bench:dro -->
"""


def test_a_section_is_replaced_in_place_and_the_text_around_it_stays(tmp_path: Path) -> None:
    doc = tmp_path / "PERFORMANCE.md"
    doc.write_text(DOC)
    write_section("epoch", "## Epoch latency\nnew epoch numbers\n", doc)
    assert doc.read_text() == DOC.replace("old epoch numbers", "new epoch numbers")


def test_a_new_section_goes_where_the_order_puts_it(tmp_path: Path) -> None:
    doc = tmp_path / "PERFORMANCE.md"
    doc.write_text(DOC)
    write_section("sim", "## Simulator\nsim numbers", doc)  # ORDER: epoch, sim, experiment, dro, ...
    text = doc.read_text()
    assert text.index("They explain") < text.index("<!-- bench:sim -->") < text.index("<!-- bench:dro -->")
    assert "<!-- bench:sim -->\n## Simulator\nsim numbers\n<!-- /bench:sim -->\n" in text
    assert text.replace("<!-- bench:sim -->\n## Simulator\nsim numbers\n<!-- /bench:sim -->\n\n", "") == DOC
    write_section("hardening", "## Hardening", doc)  # last in ORDER: appended
    assert doc.read_text().endswith(
        "<!-- /bench:dro -->\n\n<!-- bench:hardening -->\n## Hardening\n<!-- /bench:hardening -->\n"
    )


def test_the_first_section_starts_a_new_document(tmp_path: Path) -> None:
    doc = tmp_path / "PERFORMANCE.md"
    write_section("dro", "## DRO\nnumbers", doc)
    text = doc.read_text()
    assert text.startswith("# Performance\n") and text.endswith(
        "<!-- bench:dro -->\n## DRO\nnumbers\n<!-- /bench:dro -->\n"
    )


def test_the_epoch_report_names_the_machine_most_scenarios_ran_on_and_the_others() -> None:
    from bench.bench_epoch import _machines

    results = {"a": {"machine": "X"}, "b": {"machine": "Y"}, "c": {"machine": "X"}, "d": {}}
    common, other = _machines(results)
    assert common == "X"
    assert other == ["b was measured on another machine: Y."]
    assert _machines({"a": {}}) == (None, [])
