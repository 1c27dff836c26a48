"""MkDocs hook: pages whose commands and output come from the code itself, so the site
cannot drift from it, and that read the same on GitHub.

A page holds generated regions, each between an opening comment and
``<!-- kincal:end -->``, with the generated Markdown in between (so the page shows real
commands and real output wherever it is read):

* ``<!-- kincal:code PATH:STEP -->``: the lines between ``# --8<-- [start:STEP]`` and
  ``# --8<-- [end:STEP]`` of the example script ``PATH`` (relative to the repository
  root, ``.sh`` or ``.py``), or the whole file without ``:STEP``;
* ``<!-- kincal:run PATH:STEP -->``: what those lines printed (stdout and stderr, in
  terminal order) when the script ran in a fresh temporary folder that looks like the
  repository root: ``examples/`` is a copy of the repository's and ``../shared/data`` the
  data sets (``$KINCAL_DATA``), so every command of a page runs as printed from the
  root of a clone.

``python docs/hooks/kincal_pages.py update`` runs the scripts and rewrites every region
(it also turns the older ``--8<--`` includes and bare ``kincal:run`` comments into
regions). The build runs every script again and **fails when a page's region differs**
from what the code prints today (timings aside), naming the page and the update command;
``tests/test_tutorials.py`` makes the same check, so no number on a page can go stale.

Two more directives are expanded at build time only: ``<!-- kincal:cli-reference -->``
becomes the reference of every ``kincal`` command, read from the command objects, and
``<!-- kincal:file PATH:NAME -->`` shows the figure ``NAME`` (``.png``, ``.svg``) that the
script wrote, or links the page (``.html``), copied into the site under ``generated/``.

Scripts on the real data sets exit with :data:`SKIP` (77) when the data are absent. The
page then shows the output recorded in ``PATH`` with the suffix ``.recorded.txt``
(committed next to the script), saying that it is recorded and when;
``tests/test_tutorials.py`` checks that the recorded output is what a fresh run prints
wherever the data are present. Record it again with
``python docs/hooks/kincal_pages.py record PATH``.

Every script of the site is started in parallel (two at a time) when the build begins.
"""

from __future__ import annotations

import datetime
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
#: Exit status of a script whose data are absent (automake's "skipped").
SKIP = 77
_RUN = re.compile(r"<!-- kincal:run (\S+?)(?::([\w-]+))? -->")
_FILE = re.compile(r"<!-- kincal:file (\S+?):(\S+) -->")
#: Files a script writes that a page may show or link (figures, reports).
_KEEP = (".png", ".svg", ".html")
_START = re.compile(r"^(\s*)# --8<-- \[start:([\w-]+)\]\s*$")
_MARK = "@@kincal-step {}@@"
_MARK_RE = re.compile(r"^@@kincal-step ([\w-]+)@@$", re.M)
_POOL: ThreadPoolExecutor | None = None
_FUTURES: dict[str, Future[Run]] = {}


@dataclass(frozen=True)
class Run:
    """One run of an example script: what it printed, step by step."""

    script: str
    status: int
    output: str          # stdout and stderr together, with the step markers
    seconds: float
    recorded: str = ""   # the recording's header line when the data were absent
    files: dict[str, bytes] = field(default_factory=dict)  # figures and reports it wrote

    def step(self, name: str | None) -> str:
        """What the script printed in step ``name`` (all of it for ``None``)."""
        if name is None:
            return _MARK_RE.sub("", self.output).strip("\n")
        parts = _MARK_RE.split(self.output)
        found = [parts[i + 1] for i in range(1, len(parts), 2) if parts[i] == name]
        if not found:
            raise KeyError(f"{self.script}: no step '{name}' (no '# --8<-- [start:{name}]')")
        return "\n".join(p.strip("\n") for p in found)


def steps(text: str) -> list[str]:
    """The step names of a script, in order."""
    return [m.group(2) for line in text.splitlines() if (m := _START.match(line))]


def _instrumented(script: Path) -> str:
    """The script with a line printing a step marker after each step's start marker."""
    out = []
    for line in script.read_text(encoding="utf-8").splitlines():
        out.append(line)
        m = _START.match(line)
        if m:
            indent, name = m.groups()
            mark = _MARK.format(name)
            out.append(f"{indent}echo '{mark}'" if script.suffix == ".sh"
                       else f"{indent}print({mark!r}, flush=True)")
    return "\n".join(out) + "\n"


def environment() -> dict[str, str]:
    """What the scripts run with: the data folder (``$KINCAL_DATA``, default the data sets
    beside the clone; a script sees it as ``../shared/data``), a 100-column plain terminal,
    one BLAS thread."""
    return dict(os.environ, KINCAL_DATA=os.environ.get("KINCAL_DATA", str(DATA)),
                COLUMNS="100", NO_COLOR="1", TERM="dumb", PYTHONUNBUFFERED="1",
                PYTHONHASHSEED="0", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


def _repository_like(tmp: Path, env: dict[str, str]) -> Path:
    """A working folder in ``tmp`` that looks like the root of a clone: ``examples/`` (a
    copy, so that outputs a setup file names land in the copy) and ``../shared/data``
    (a link to the data sets)."""
    work = tmp / "work"
    work.mkdir()
    shutil.copytree(ROOT / "examples", work / "examples",
                    ignore=shutil.ignore_patterns("__pycache__", "out"))
    (tmp / "shared").mkdir()
    (tmp / "shared" / "data").symlink_to(Path(env["KINCAL_DATA"]).resolve(),
                                         target_is_directory=True)
    return work


def execute(rel: str, env: dict[str, str] | None = None) -> Run:
    """Run ``rel`` in a fresh temporary folder; the skip status is returned, not raised."""
    script = ROOT / rel
    if not script.is_file():
        raise FileNotFoundError(f"example script not found: {rel}")
    code = _instrumented(script)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kincal-docs-") as tmp:
        path = Path(tmp) / f"_tutorial{script.suffix}"
        path.write_text(code, encoding="utf-8")
        cmd = (["bash", str(path)] if script.suffix == ".sh"
               else [sys.executable, str(path)])
        work = _repository_like(Path(tmp), env or environment())
        res = subprocess.run(cmd, cwd=work, env=env or environment(), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, errors="replace",
                             timeout=900)
        files = {p.relative_to(work).as_posix(): p.read_bytes() for p in sorted(work.rglob("*"))
                 if p.suffix in _KEEP and p.is_file() and not p.is_symlink()
                 and len(p.relative_to(work).parts) <= 2
                 and p.relative_to(work).parts[0] != "examples"}
    output = "\n".join(line.rstrip() for line in res.stdout.replace(tmp, ".").splitlines())
    return Run(rel, res.returncode, output, time.perf_counter() - t0, files=files)


def recording(rel: str) -> Path:
    """Where the recorded output of a real-data script lives."""
    return (ROOT / rel).with_suffix(".recorded.txt")


def read_recording(rel: str) -> Run:
    """The recorded run of ``rel``: header line, then the output with its step markers."""
    path = recording(rel)
    if not path.is_file():
        raise RuntimeError(f"{rel} skipped (its data are absent) and has no recorded output "
                           f"{path.relative_to(ROOT)}")
    header, _, output = path.read_text(encoding="utf-8").partition("\n")
    return Run(rel, 0, output, 0.0, recorded=header.lstrip("# ").strip())


def run_example(rel: str) -> Run:
    """The run of ``rel`` to show: a fresh one, or the recorded one if its data are absent."""
    run = execute(rel)
    if run.status == SKIP:
        return read_recording(rel)
    if run.status != 0:
        raise RuntimeError(f"{rel} failed (exit {run.status}):\n{run.output}")
    return run


def record(rel: str) -> Path:
    """Run ``rel`` on the real data and write its recorded output next to it."""
    run = execute(rel)
    if run.status != 0:
        raise SystemExit(f"{rel}: exit {run.status} (data in {environment()['KINCAL_DATA']}?)"
                         f"\n{run.output}")
    from kincal import __version__

    header = (f"# recorded on {datetime.date.today().isoformat()} with kincal {__version__} "
              "on the real data sets (../shared/data)")
    path = recording(rel)
    path.write_text(header + "\n" + run.output, encoding="utf-8")
    return path


# -- generated regions of a page ----------------------------------------------------------

_REGION = re.compile(r"<!-- kincal:(run|code) (\S+?)(?::([\w-]+))? -->\n"
                     r"((?:(?!<!-- kincal:).)*?)<!-- kincal:end -->\n?", re.S)
#: The older forms: a fenced ``--8<--`` include and a bare ``kincal:run`` comment.
_OLD_INCLUDE = re.compile(r"```\w*\n--8<-- \"(\S+?)(?::([\w-]+))?\"\n```\n?")
_OLD_RUN = re.compile(r"<!-- kincal:run (\S+?)(?::([\w-]+))? -->\n?")
_END = "<!-- kincal:end -->"
_ANY_MARKER = re.compile(r"^\s*# --8<-- \[(?:start|end):[\w-]+\]\s*$")
_LANGUAGES = {".sh": "bash", ".py": "python", ".yaml": "yaml", ".yml": "yaml"}
#: Timings and durations, which differ from run to run: "(0.03 s)", "5.4 s", "[1.5 s]".
_TIME = re.compile(r"\d+(?:\.\d+)?(?:e-?\d+)? ?(?:s|ms|µs)\b")


def normalised(text: str) -> str:
    """Text without its timings (what may differ between two runs of one script)."""
    return _TIME.sub("<time>", text)


def script_lines(rel: str, step: str | None) -> str:
    """The lines of ``rel`` between the markers of ``step`` (the whole file for None)."""
    lines = (ROOT / rel).read_text(encoding="utf-8").splitlines()
    if step is None:        # the whole file, without the step markers
        return "\n".join(line for line in lines if not _ANY_MARKER.match(line)).strip("\n")
    inside, out, seen = False, [], False
    for line in lines:
        m = _START.match(line)
        if m and m.group(2) == step:
            inside, seen = True, True
            continue
        if inside and re.match(rf"^\s*# --8<-- \[end:{re.escape(step)}\]\s*$", line):
            inside = False
            continue
        if inside:
            out.append(line)
    if not seen:
        raise KeyError(f"{rel}: no step '{step}' (no '# --8<-- [start:{step}]')")
    return "\n".join(out).strip("\n")


def code_body(rel: str, step: str | None) -> str:
    """A code region's Markdown: the script's lines in a fenced block."""
    lang = _LANGUAGES.get(Path(rel).suffix, "")
    return f"```{lang}\n{script_lines(rel, step)}\n```\n"


def run_body(run: Run, step: str | None) -> str:
    """A run region's Markdown: what the step printed, and where recorded, when."""
    block = "```text\n" + run.step(step) + "\n```\n"
    if not run.recorded:
        return block
    return (f"*Output {run.recorded} "
            f"(`{Path(run.script).with_suffix('.recorded.txt').as_posix()}`; the tests "
            f"check it against a fresh run wherever the data are).*\n\n{block}")


def shown_run(rel: str, run_of: Any) -> Run:
    """The run a page shows: the recording of a real-data script (the same wherever the
    page is generated, with or without the data), else ``run_of(rel)``."""
    return read_recording(rel) if recording(rel).is_file() else run_of(rel)


def _region(kind: str, rel: str, step: str | None, body: str) -> str:
    head = f"<!-- kincal:{kind} {rel}{':' + step if step else ''} -->"
    return f"{head}\n{body}{_END}\n"


def upgraded(markdown: str) -> str:
    """A page with the older include / run forms turned into (empty) regions."""
    markdown = _OLD_INCLUDE.sub(lambda m: _region("code", m.group(1), m.group(2), ""),
                                markdown)
    spans = [(m.start(), m.end()) for m in _REGION.finditer(markdown)]

    def bare(m: re.Match[str]) -> str:
        if any(a <= m.start() < b for a, b in spans):
            return m.group(0)
        return _region("run", m.group(1), m.group(2), "")
    return _OLD_RUN.sub(bare, markdown)


def regenerated(markdown: str, run_of: Any) -> str:
    """The page with every region's body generated again (``run_of(rel)`` gives a Run)."""
    def body(m: re.Match[str]) -> str:
        kind, rel, step = m.group(1), m.group(2), m.group(3)
        text = (code_body(rel, step) if kind == "code"
                else run_body(shown_run(rel, run_of), step))
        return _region(kind, rel, step, text)
    return _REGION.sub(body, upgraded(markdown))


def stale_regions(markdown: str, run_of: Any, only: str | None = None) -> list[str]:
    """The regions of a page whose shown text differs from what the code gives today
    (``only``: the run regions of that script only, besides every code region)."""
    stale = []
    for m in _REGION.finditer(markdown):
        kind, rel, step, shown = m.group(1), m.group(2), m.group(3), m.group(4)
        if kind == "run" and only is not None and rel != only:
            continue
        today = (code_body(rel, step) if kind == "code"
                 else run_body(shown_run(rel, run_of), step))
        if normalised(shown) != normalised(today):
            stale.append(f"{kind} {rel}{':' + step if step else ''}")
    return stale


def update(pages: list[Path]) -> list[Path]:
    """Run the scripts of ``pages`` (two at a time) and rewrite their regions; returns the
    pages that changed."""
    original = {page: page.read_text(encoding="utf-8") for page in pages}
    texts = {page: upgraded(text) for page, text in original.items()}
    wanted = list(dict.fromkeys(m.group(2) for text in texts.values()
                                for m in _REGION.finditer(text)
                                if m.group(1) == "run" and not recording(m.group(2)).is_file()))
    with ThreadPoolExecutor(max_workers=int(os.environ.get("KINCAL_DOCS_JOBS", "2"))) as pool:
        runs = dict(zip(wanted, pool.map(run_example, wanted), strict=True))
    changed = []
    for page, text in texts.items():
        new = regenerated(text, runs.__getitem__)
        if new != original[page]:
            if page.read_text(encoding="utf-8") != original[page]:
                raise SystemExit(f"{page}: changed while the scripts ran; run the update again")
            page.write_text(new, encoding="utf-8")
            changed.append(page)
    return changed


# -- the CLI reference ---------------------------------------------------------------------

_TYPES = {"str": "TEXT", "int": "INTEGER", "int range": "INTEGER", "float": "NUMBER",
          "float range": "NUMBER", "path": "PATH", "boolean": "BOOLEAN"}


def _option_row(p: Any) -> str:
    names = ", ".join(f"`{o}`" for o in [*p.opts, *p.secondary_opts])
    kind = p.metavar or _TYPES.get(p.type.name, p.type.name.upper())
    meta = "" if getattr(p, "is_flag", False) else f" `{kind}`"
    default = p.default
    show = ("" if default in (None, False, (), []) or callable(default)
            else f" (default: `{default}`)")
    text = (p.help or "").replace("|", "\\|").replace("\n", " ")
    return f"| {names}{meta} | {text}{show} |"


def _command_markdown(name: str, cmd: Any, ctx: Any) -> list[str]:
    out = [f"## `kincal {name}`", ""]
    doc = (cmd.help or "").strip()
    if doc:
        out += [doc.replace("\b\n", ""), ""]
    sub_ctx = type(ctx)(cmd, info_name=name, parent=ctx)
    out += ["```", " ".join(cmd.collect_usage_pieces(sub_ctx)).join(
        [f"kincal {name} ", ""]), "```", ""]
    # typer may build its commands with its own copy of click: compare by kind, not class
    args = [p for p in cmd.params if p.param_type_name == "argument"]
    opts = [p for p in cmd.params if p.param_type_name == "option" and not p.hidden]
    if args:
        out += ["| argument | |", "|---|---|"]
        out += [f"| `{a.human_readable_name}` | {(getattr(a, 'help', '') or '').strip()} |"
                for a in args]
        out.append("")
    if opts:
        out += ["| option | |", "|---|---|"] + [_option_row(o) for o in opts] + [""]
    if getattr(cmd, "commands", None):
        for sub_name, sub in sorted(cmd.commands.items()):
            if not getattr(sub, "hidden", False):
                out += _command_markdown(f"{name} {sub_name}", sub, sub_ctx)
    return out


def cli_reference() -> str:
    """The reference of every visible ``kincal`` command, in ``kincal --help`` order."""
    import typer

    from kincal.cli import app

    group = typer.main.get_command(app)
    ctx = group.context_class(group, info_name="kincal")
    lines: list[str] = []
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is not None and not cmd.hidden:
            lines += _command_markdown(name, cmd, ctx)
    return "\n".join(lines)


# -- the hook ------------------------------------------------------------------------------

def site_pages() -> list[Path]:
    """Every page that may hold generated regions: the site's and the README."""
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def scripts_of(markdown: str) -> list[str]:
    """The example scripts a page runs (for their output or the files they write)."""
    return list(dict.fromkeys([*(m.group(1) for m in _RUN.finditer(markdown)),
                               *(m.group(1) for m in _FILE.finditer(markdown))]))


def on_pre_build(config: Any) -> None:
    """Start every script the pages run, two at a time, before the pages are rendered."""
    global _POOL
    _FUTURES.clear()
    _POOL = ThreadPoolExecutor(max_workers=int(os.environ.get("KINCAL_DOCS_JOBS", "2")))
    docs = Path(config["docs_dir"])
    _WRITTEN.clear()
    wanted = [s for page in sorted(docs.rglob("*.md"))
              for s in scripts_of(page.read_text(encoding="utf-8"))]
    for rel in dict.fromkeys(wanted):
        _FUTURES[rel] = _POOL.submit(run_example, rel)


def _result(rel: str) -> Run:
    if rel not in _FUTURES:
        assert _POOL is not None
        _FUTURES[rel] = _POOL.submit(run_example, rel)
    return _FUTURES[rel].result()


def generated_path(rel: str, name: str) -> str:
    """Where a file written by script ``rel`` lands in the site."""
    return f"generated/{Path(rel).stem}/{name}"


def _render_file(match: re.Match[str], page: Any) -> str:
    rel, name = match.groups()
    run = _result(rel)
    if name not in run.files:
        if run.recorded:
            return f"*(`{name}` is written by the script; not available in recorded output.)*"
        raise RuntimeError(f"{page.file.src_uri}: {rel} wrote no {name} "
                           f"(it wrote: {', '.join(run.files) or 'nothing'})")
    _WRITTEN[generated_path(rel, name)] = run.files[name]
    url = "../" * page.url.count("/") + generated_path(rel, name)
    if name.endswith(".html"):
        return (f'<a href="{url}">{name}</a> (the file this build\'s run wrote; opens the '
                "page itself)")
    return (f'<figure><img src="{url}" alt="{name}" loading="lazy">'
            f"<figcaption>{name}, as written by this build's run of "
            f"<code>{Path(rel).name}</code></figcaption></figure>")


_WRITTEN: dict[str, bytes] = {}

#: A Sphinx cross-reference role as Markdown renders a docstring's ``:class:`~a.b.C```.
_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):<code>(~?)([^<]+)</code>")


def sphinx_roles(html: str) -> str:
    """The docstrings' Sphinx roles as plain code: ``:class:`~kincal.robots.chain.Robot```
    reads ``Robot`` (``~``: the last component), ``:mod:`kincal.io``` reads ``kincal.io``;
    mkdocstrings renders docstrings as Markdown, where the role would show as text."""
    return _ROLE.sub(lambda m: "<code>" + (m.group(2).rsplit(".", 1)[-1] if m.group(1)
                                            else m.group(2)) + "</code>", html)


def on_page_content(html: str, page: Any, config: Any, files: Any) -> str:
    return sphinx_roles(html)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if "<!-- kincal:cli-reference -->" in markdown:
        markdown = markdown.replace("<!-- kincal:cli-reference -->", cli_reference())
    markdown = _FILE.sub(lambda m: _render_file(m, page), markdown)
    stale = stale_regions(upgraded(markdown), _result)
    if stale or _OLD_INCLUDE.search(markdown) or upgraded(markdown) != markdown:
        raise RuntimeError(
            f"{page.file.src_uri}: the shown output or code is stale or not generated "
            f"({', '.join(stale) or 'an include or run comment without its region'}); "
            "run: python docs/hooks/kincal_pages.py update")
    return regenerated(markdown, _result)


def on_post_build(config: Any) -> None:
    from mkdocs.utils import log

    for rel, data in _WRITTEN.items():
        out = Path(config["site_dir"]) / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    runs = [f.result() for f in _FUTURES.values()]
    for run in sorted(runs, key=lambda r: -r.seconds):
        log.info(f"kincal example {run.script}: "
                 + (f"{run.seconds:.1f} s" if not run.recorded else "recorded output"))
    if _POOL is not None:
        _POOL.shutdown()


if __name__ == "__main__":
    _USAGE = ("usage: python docs/hooks/kincal_pages.py record SCRIPT... | update [PAGE...]")
    if len(sys.argv) < 2 or sys.argv[1] not in ("record", "update"):
        raise SystemExit(_USAGE)
    if sys.argv[1] == "record":
        if len(sys.argv) < 3:
            raise SystemExit(_USAGE)
        for rel in sys.argv[2:]:
            print(f"recorded -> {record(rel).relative_to(ROOT)}")
    else:
        chosen = ([Path(a).resolve() for a in sys.argv[2:]] if len(sys.argv) > 2
                  else site_pages())
        for page in update(chosen):
            print(f"updated {page.relative_to(ROOT)}")
