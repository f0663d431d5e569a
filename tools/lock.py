"""Write ``constraints.txt``: the exact versions installed in this environment of everything
``handx-jax[dev]`` needs, directly or not (``make lock``).

``make venv`` / ``make test`` / ``make demo`` install with ``uv pip install -c constraints.txt -e '.[dev]'`` (pip where uv cannot be had),
so a fresh clone gets the versions the suite last passed with instead of whatever is newest that day.
Only the project's requirement closure is written (walked through ``importlib.metadata``, markers
evaluated for this interpreter), not ``pip freeze``: tools that happen to share the environment
(a notebook server, a cluster client) are not the project's and must not constrain it.

    python tools/lock.py                 # print the constraints
    python tools/lock.py -o constraints.txt
"""

from __future__ import annotations

import argparse
import platform
import re
import sys
from importlib import metadata
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement

ROOT = "handx-jax"


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def closure(root: str = ROOT, extras: tuple[str, ...] = ("dev",)) -> dict[str, str]:
    """{canonical name: installed version} of ``root`` with ``extras`` and everything it requires."""
    env = default_environment()
    installed = {canonical(d.metadata["Name"]): d for d in metadata.distributions()}  # one scan of sys.path
    seen: dict[str, str] = {}
    todo = [(root, frozenset(extras))]
    done: set[tuple[str, frozenset]] = set()
    while todo:
        name, ext = todo.pop()
        if (canonical(name), ext) in done:
            continue
        done.add((canonical(name), ext))
        dist = installed.get(canonical(name))
        if dist is None:
            continue  # required on another platform or by an extra not installed: nothing to pin
        seen[canonical(dist.metadata["Name"])] = dist.version
        for line in dist.requires or []:
            req = Requirement(line)
            if req.marker is not None and not any(req.marker.evaluate({**env, "extra": e}) for e in (*ext, "")):
                continue
            todo.append((req.name, frozenset(req.extras)))
    seen.pop(canonical(root), None)  # the project itself is installed editable, from the clone
    return seen


def render(pins: dict[str, str]) -> str:
    head = (f"# Versions the test suite last passed with (make lock, tools/lock.py): Python "
            f"{platform.python_version()}, {platform.system()} {platform.machine()}.\n"
            "# make installs with `uv pip install -c constraints.txt -e '.[dev]'` (pip where uv cannot be had); `make test CONSTRAINTS=` ignores it.\n")
    return head + "".join(f"{n}=={v}\n" for n, v in sorted(pins.items()))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--out", help="file to write (default: print)")
    a = p.parse_args(argv)
    pins = closure()
    if not pins:
        print(f"error: {ROOT} is not installed in {sys.prefix}; run `make venv` first", file=sys.stderr)
        return 1
    text = render(pins)
    if a.out:
        tmp = Path(a.out).with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(a.out)
        print(f"wrote {a.out} ({len(pins)} packages)")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
