"""Start-up time of every light ``kincal`` command against ``python -c "import numpy"``.

Each command runs in a fresh interpreter (what a user waits for at the prompt), the
commands interleaved round after round (A B C ... A B C ...) so that the machine's load
hits all alike; the table gives the median of the rounds and its ratio to the baseline
of the same rounds.  Target: the light commands under 0.3 s.

    python benchmarks/startup.py [--repeats 9] [--all]

``--all`` adds ``kincal COMMAND --help`` for every command.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys

from timing import interleaved

LIGHT = [
    ["--help"],
    ["--version"],
    ["robots"],
    ["show", "puma560"],
    ["fk", "puma560", "--q", "0,0.5,0,0,0,0"],
    ["jacobian", "puma560", "--q", "0,0.5,0,0,0,0"],
]
TARGET = 0.3   # s


def _kincal() -> list[str]:
    exe = shutil.which("kincal")
    return [exe] if exe else [sys.executable, "-m", "kincal.cli"]


def _run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {done.stderr.decode()[-300:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9, help="interleaved rounds (>= 5)")
    ap.add_argument("--all", action="store_true", help="also COMMAND --help of every command")
    args = ap.parse_args()
    kincal = _kincal()
    cases = {"python -c 'import numpy'": [sys.executable, "-c", "import numpy"]}
    commands = list(LIGHT)
    if args.all:
        import typer

        from kincal.cli import app

        commands += [[name, "--help"] for name in typer.main.get_command(app).commands]
    for c in commands:
        cases["kincal " + " ".join(c)] = kincal + c
    # one untimed run each warms the file cache; then rounds in rotated order
    t = interleaved({k: lambda cmd=cmd: _run(cmd) for k, cmd in cases.items()},
                    rounds=max(5, args.repeats))
    base = "python -c 'import numpy'"
    width = max(map(len, cases))
    print(f"start-up time, median of {max(5, args.repeats)} interleaved rounds "
          f"({sys.executable}, {kincal[0]})")
    print(f"{'command':<{width}}  {'median':>8}  {'x numpy':>8}  {'< 0.3 s':>7}")
    for k in cases:
        m = t.median(k)
        ok = "" if k.startswith("python") else ("yes" if m < TARGET else "NO")
        print(f"{k:<{width}}  {m * 1e3:6.0f} ms  {t.ratio(k, base):8.2f}  {ok:>7}")


if __name__ == "__main__":
    main()
