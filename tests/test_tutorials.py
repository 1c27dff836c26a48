"""Every tutorial script runs, and every page shows what it prints today.

The documentation pages (docs/) hold each tutorial's commands, copied from a script under
``examples/tutorials/``, and its real output, in generated regions
(docs/hooks/kincal_pages.py), so they read the same on GitHub and on the site. This module
runs the same scripts the same way and fails when a page's region differs from the
script's lines or from what it printed (apart from timings): run
``python docs/hooks/kincal_pages.py update``. A script on the real data sets exits with
the hook's skip status when the data are absent; its committed recording is then what the
pages show, and here, where the data are present, the recording must equal a fresh run.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "examples" / "tutorials"
DOCS = ROOT / "docs"

_spec = importlib.util.spec_from_file_location("kincal_pages", DOCS / "hooks" / "kincal_pages.py")
assert _spec and _spec.loader
pages = importlib.util.module_from_spec(_spec)
sys.modules["kincal_pages"] = pages
_spec.loader.exec_module(pages)

SCRIPTS = sorted(p.relative_to(ROOT).as_posix() for p in TUTORIALS.iterdir()
                 if p.suffix in (".sh", ".py"))


def _page_directives() -> list[tuple[str, str, str | None]]:
    found = []
    for page in pages.site_pages():
        text = page.read_text(encoding="utf-8")
        for m in pages._RUN.finditer(text):
            found.append((page.relative_to(ROOT).as_posix(), m.group(1), m.group(2)))
    return found


normalised = pages.normalised


#: Real-data scripts too slow for the suite's time budget (about ten calibrations each):
#: here their pages must show their recording; the site build runs them again (and fails
#: on a stale region), as does this test with KINCAL_SLOW_TUTORIALS=1.
SLOW = {"examples/tutorials/more-robots.sh"}


def _pages_show(script: str, run) -> None:
    for page in pages.site_pages():
        text = page.read_text(encoding="utf-8")
        if script not in pages.scripts_of(text):
            continue
        stale = pages.stale_regions(text, {script: run}.__getitem__, only=script)
        assert not stale, (f"{page.relative_to(ROOT)}: shown output or code differs from "
                           f"what {script} gives today ({', '.join(stale)}); run: python "
                           "docs/hooks/kincal_pages.py update")


@pytest.mark.parametrize("script", SCRIPTS)
def test_tutorial_script_runs(script: str) -> None:
    if script in SLOW and not os.environ.get("KINCAL_SLOW_TUTORIALS"):
        recorded = pages.read_recording(script)        # shown as a fresh run shows it
        _pages_show(script, dataclasses.replace(recorded, recorded=""))
        pytest.skip(f"{script}: too slow for the suite (KINCAL_SLOW_TUTORIALS=1 runs it); "
                    "its pages show its recording")
    run = pages.execute(script)
    if run.status == pages.SKIP:
        assert pages.recording(script).is_file(), (
            f"{script} skips without data but has no recording; run "
            f"`python docs/hooks/kincal_pages.py record {script}` where the data are")
        pytest.skip(f"{script}: real data not found in {pages.environment()['KINCAL_DATA']}; "
                    "the site shows its recorded output")
    assert run.status == 0, f"{script} failed (exit {run.status}):\n{run.output}"
    for name in pages.steps((ROOT / script).read_text(encoding="utf-8")):
        assert run.step(name).strip(), f"{script}: step '{name}' printed nothing"
    assert "Traceback" not in run.output, run.output
    if pages.recording(script).is_file():
        recorded = pages.read_recording(script)
        assert normalised(recorded.output) == normalised(run.output), (
            f"{script}: the recorded output differs from a fresh run on the data; record it "
            f"again: python docs/hooks/kincal_pages.py record {script}")
    _pages_show(script, run)


def test_every_page_region_is_generated() -> None:
    """No include or run comment without its generated region (GitHub shows regions only),
    and every code region is the script's lines as they are."""
    for page in pages.site_pages():
        text = page.read_text(encoding="utf-8")
        assert pages.upgraded(text) == text, (
            f"{page.relative_to(ROOT)}: an include or run comment without its region; run: "
            "python docs/hooks/kincal_pages.py update")
        assert not pages._OLD_INCLUDE.search(text), (f"{page.relative_to(ROOT)}: an include "
                                                     "GitHub cannot show")


def test_every_script_is_on_a_page_and_every_page_step_exists() -> None:
    used = _page_directives()
    assert {s for _, s, _ in used} == set(SCRIPTS), "a tutorial script no page shows, or a "\
        "page that runs a script that does not exist"
    for page, script, step in used:
        if step is not None:
            assert step in pages.steps((ROOT / script).read_text(encoding="utf-8")), \
                f"{page}: {script} has no step '{step}'"


def test_no_hidden_alias_is_left() -> None:
    """Each option has one spelling: no hidden option or command remains (the aliases
    ``--noise-mm``, ``--out``, ``fivebar-thesis`` of an unreleased version are gone), and
    neither scripts nor pages teach them."""
    import typer

    from kincal.cli import app

    hidden: set[str] = set()
    seen: set[str] = set()

    def walk(cmd) -> None:  # typer's own click: compare by kind, not class
        for p in cmd.params:
            seen.update(p.opts)
            if p.param_type_name == "option" and p.hidden:
                hidden.update(o for o in p.opts if o.startswith("--"))
        if getattr(cmd, "commands", None):
            for name, sub in cmd.commands.items():
                if sub.hidden:
                    hidden.add(f"kincal {name} ")
                walk(sub)

    walk(typer.main.get_command(app))
    assert {"--noise", "--marker", "--min-distance", "--out-dir"} <= seen   # the walk works
    assert hidden == set()
    for script in SCRIPTS:
        text = (ROOT / script).read_text(encoding="utf-8")
        for alias in ("--noise-mm", "--noise-deg", "--marker-mm", "--min-distance-deg",
                      "--orientation-noise-deg", "fivebar-thesis"):
            assert not re.search(re.escape(alias) + r"(?![\w-])", text), f"{script}: {alias}"
    for page in DOCS.rglob("*.md"):
        text = page.read_text(encoding="utf-8")
        for alias in ("--noise-mm", "--tolerance-mm", "fivebar-thesis"):
            assert alias not in text or page.name == "conventions.md", f"{page}: {alias}"


def test_recorded_outputs_say_when_and_belong_to_a_script() -> None:
    for path in TUTORIALS.glob("*.recorded.txt"):
        scripts = [s for s in SCRIPTS if pages.recording(s) == path]
        assert scripts, f"{path.name}: no script records here"
        first = path.read_text(encoding="utf-8").partition("\n")[0]
        assert first.startswith("# recorded on "), f"{path.name}: {first!r}"
