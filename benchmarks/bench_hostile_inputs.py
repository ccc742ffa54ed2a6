"""Issue 19's numbers, side by side in one run:

1. ``allorules --help``: the command line as it is (only the chosen command's module imported)
   against every command module imported up front (what it did before).
2. YAML: a nine-levels-of-nine alias bomb, a 10 MB ruleset, and a ruleset just under the values
   limit, through ``allorules ruleset check`` (wall time of the process).
3. Reading an OBJ: ``allorules.mesh.load.load_mesh`` (encoding, binary and 0-index checks) against
   ``trimesh.load`` of the same file.

Run: .venv/bin/python benchmarks/bench_hostile_inputs.py [--quick]
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMAND = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main(sys.argv[1:]))"]


def wall(command: list[str]) -> float:
    """Seconds one child process takes."""
    start = time.perf_counter()
    subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600, cwd=tempfile.gettempdir())
    return time.perf_counter() - start


def help_times(repeats: int, before: Path | None) -> None:
    import compileall

    import allorules

    # byte-compile both trees first, as an installed package is (an editable checkout with
    # PYTHONDONTWRITEBYTECODE set would otherwise compile every module on every run)
    for tree in [Path(allorules.__file__).parent] + ([before / "allorules"] if before else []):
        compileall.compile_dir(str(tree), quiet=1)
    lazy = [*COMMAND, "--help"]
    eager = [sys.executable, "-c", "from allorules.cli import build_parser; build_parser().print_help()"]
    bare = [sys.executable, "-c", "pass"]
    commands = {"python -c pass": bare, "allorules --help (on demand)": lazy,
                "every command imported up front": eager}
    if before is not None:   # an older checkout, e.g. git archive 1ddf091 allorules | tar -x -C /tmp/before
        import site

        # without site (-S) the editable install's finder is not loaded: the checkout is imported
        path = ":".join([str(before), *site.getsitepackages()])
        commands["--help of the checkout in --before"] = ["env", f"PYTHONPATH={path}", sys.executable, "-S",
                                                          *COMMAND[1:], "--help"]
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeats):   # interleaved, so that the machine's load falls on all alike
        for name, command in commands.items():
            times[name].append(wall(command))
    print("\n## allorules --help (median of %d, seconds)" % repeats)
    for name, values in times.items():
        print(f"{name:<34} {statistics.median(values):.3f}  (min {min(values):.3f})")


def alias_bomb() -> str:
    lines = ["name: bomb", "regions: [head]", "a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]" for k in range(1, 9)]
    return "\n".join(lines + ["rules: *a8"]) + "\n"


def ruleset_of(rules: int) -> str:
    lines = ["name: big", "regions: [head, neck, chest, abdomen, forelimbs, hindlimbs]", "rules:"]
    for index in range(rules):
        lines += [f"  - id: rule-{index}", "    region: head", "    measure: mass", "    exponent: 0.75"]
    return "\n".join(lines) + "\n"


def yaml_times(folder: Path, quick: bool) -> None:
    cases = {"alias bomb, 9 levels of 9 (387M values)": alias_bomb(),
             "10 MB ruleset (136,000 rules)": ruleset_of(136_000)}
    if not quick:
        cases["1.4 MB ruleset, 19,900 rules (99,500 values)"] = ruleset_of(19_900)
    print("\n## allorules ruleset check (one run each)")
    for name, text in cases.items():
        path = folder / "case.yaml"
        path.write_text(text)
        start = time.perf_counter()
        result = subprocess.run([*COMMAND, "ruleset", "check", str(path)], capture_output=True, text=True, timeout=600)
        seconds = time.perf_counter() - start
        said = (result.stderr or result.stdout).strip().splitlines()[0][:110]
        print(f"{name:<46} {seconds:6.2f} s  exit {result.returncode}: {said}")


def obj_times(folder: Path, repeats: int) -> None:
    import trimesh

    from allorules.mesh.load import load_mesh

    print("\n## reading an OBJ (median of %d, seconds)" % repeats)
    for subdivisions in (6, 8):
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
        path = folder / f"sphere{subdivisions}.obj"
        sphere.export(path)
        ours, theirs = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            trimesh.load(path, force="mesh", process=False)
            theirs.append(time.perf_counter() - start)
            start = time.perf_counter()
            load_mesh(path)
            ours.append(time.perf_counter() - start)
        size = path.stat().st_size / 1e6
        print(f"{len(sphere.vertices):>7} vertices ({size:.0f} MB): trimesh.load {statistics.median(theirs):.2f}, "
              f"load_mesh {statistics.median(ours):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, no at-the-limit ruleset")
    parser.add_argument("--before", type=Path, metavar="DIR",
                        help="also time --help of an older checkout of the package (its folder, on PYTHONPATH)")
    arguments = parser.parse_args()
    repeats = 3 if arguments.quick else 7
    help_times(repeats, arguments.before)
    with tempfile.TemporaryDirectory() as folder:
        yaml_times(Path(folder), arguments.quick)
        obj_times(Path(folder), 1 if arguments.quick else 3)


if __name__ == "__main__":
    main()
