"""MkDocs hook: pages generated from the code itself, so the site cannot drift from it.

* ``<!-- kincal:cli-reference -->`` becomes the reference of every ``kincal`` command,
  read from the command objects (names, arguments, options, defaults, help);
* ``<!-- kincal:run PATH -->`` runs the example script ``PATH`` (relative to the
  repository root) in a fresh temporary folder and inserts what it printed, so every
  tutorial shows real output of the code being documented; a script that fails stops
  the build.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
_RUN = re.compile(r"<!-- kincal:run (\S+) -->")
_CACHE: dict[str, str] = {}


def _option_row(p: Any) -> str:
    names = ", ".join(f"`{o}`" for o in [*p.opts, *p.secondary_opts])
    meta = "" if getattr(p, "is_flag", False) else f" `{p.metavar or p.type.name.upper()}`"
    default = p.default
    show = "" if default in (None, False, (), []) or callable(default) else f" (default: `{default}`)"
    text = (p.help or "").replace("|", "\\|").replace("\n", " ")
    return f"| {names}{meta} | {text}{show} |"


def _command_markdown(name: str, cmd: Any, ctx: Any) -> list[str]:
    import click

    out = [f"## `kincal {name}`", ""]
    doc = (cmd.help or "").strip()
    if doc:
        out += [doc.replace("\b\n", ""), ""]
    sub_ctx = click.Context(cmd, info_name=name, parent=ctx)
    out += ["```", " ".join(cmd.collect_usage_pieces(sub_ctx)).join(
        [f"kincal {name} ", ""]), "```", ""]
    args = [p for p in cmd.params if isinstance(p, click.Argument)]
    opts = [p for p in cmd.params if isinstance(p, click.Option) and not p.hidden]
    if args:
        out += ["| argument | |", "|---|---|"]
        out += [f"| `{a.human_readable_name}` | {(getattr(a, 'help', '') or '').strip()} |"
                for a in args]
        out.append("")
    if opts:
        out += ["| option | |", "|---|---|"] + [_option_row(o) for o in opts] + [""]
    if isinstance(cmd, click.Group):
        for sub_name, sub in sorted(cmd.commands.items()):
            if not getattr(sub, "hidden", False):
                out += _command_markdown(f"{name} {sub_name}", sub, sub_ctx)
    return out


def cli_reference() -> str:
    """The reference of every visible ``kincal`` command, in ``kincal --help`` order."""
    import click
    import typer

    from kincal.cli import app

    group = typer.main.get_command(app)
    ctx = click.Context(group, info_name="kincal")
    lines: list[str] = []
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is not None and not cmd.hidden:
            lines += _command_markdown(name, cmd, ctx)
    return "\n".join(lines)


def run_example(rel: str) -> str:
    """Run ``rel`` (a .sh or .py script under the repository) in a fresh folder."""
    if rel in _CACHE:
        return _CACHE[rel]
    script = ROOT / rel
    cmd = ["bash", str(script)] if script.suffix == ".sh" else [sys.executable, str(script)]
    env = dict(os.environ, KINCAL_DATA=str(ROOT.parent / "shared" / "data"),
               COLUMNS="100", NO_COLOR="1", TERM="dumb")
    with tempfile.TemporaryDirectory(prefix="kincal-docs-") as tmp:
        res = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True,
                             timeout=600)
    if res.returncode != 0:
        raise RuntimeError(f"{rel} failed (exit {res.returncode}):\n{res.stdout}\n{res.stderr}")
    _CACHE[rel] = res.stdout.rstrip()
    return _CACHE[rel]


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if "<!-- kincal:cli-reference -->" in markdown:
        markdown = markdown.replace("<!-- kincal:cli-reference -->", cli_reference())
    return _RUN.sub(lambda m: "```text\n" + run_example(m.group(1)) + "\n```", markdown)
