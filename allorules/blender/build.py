"""Build the Blender extension file: one .zip a user installs from Blender's preferences.

The archive (Blender 4.2+ extension format) holds ``blender_manifest.toml``, a two-function
``__init__.py`` that registers :mod:`allorules.blender`, and ``wheels/``: the allorules wheel and
the wheels of its dependencies for one platform, listed in the manifest. Blender installs those
wheels into the extension's own site-packages; numpy is left out because Blender ships it (its
own numpy 1.26 in Blender 4.2 to 5.0, which is why the dependencies are resolved against it).

Two ways (see docs/blender.md)::

    python -m allorules.blender.build -o allorules-blender.zip                # fetches wheels (network)
    python -m allorules.blender.build --fetch-wheels wheels/                  # only fetch, for later
    python -m allorules.blender.build --wheels wheels/ -o allorules-blender.zip   # offline

``--wheels DIR`` must hold the allorules wheel (``pip wheel . --no-deps -w DIR``) and every
dependency's wheel for the platform; what is missing is named. No network is used then.
"""
from __future__ import annotations

import argparse
import email.parser
import re
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from allorules.errors import AllorulesError

EXTENSION_ID = "allorules"
BLENDER_VERSION_MIN = "4.2.0"
BLENDER_NUMPY = "1.26.4"               # numpy as Blender 4.2 to 5.0 ship it
PYTHON_VERSION = "3.11"                # Blender 4.2 to 5.0
SHIPPED_BY_BLENDER = {"numpy"}         # never bundled: Blender's own copy is used
# Blender platform name -> pip platform tags (newest first) for ``pip download``
PLATFORMS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_14_0_arm64", "macosx_12_0_arm64", "macosx_11_0_arm64"),
    "macos-x64": ("macosx_10_13_x86_64", "macosx_10_9_x86_64"),
}
# which wheel platform tags fit a Blender platform
_TAG_PATTERN = {
    "linux-x64": re.compile(r"^(many)?linux.*x86_64$"),
    "windows-x64": re.compile(r"^win_amd64$"),
    "macos-arm64": re.compile(r"^macosx_.*(arm64|universal2)$"),
    "macos-x64": re.compile(r"^macosx_.*(x86_64|intel|universal2)$"),
}

INIT_PY = '''"""allorules as a Blender extension: the add-on itself is allorules.blender, from the bundled wheel."""


def register():
    from allorules.blender import register as register_allorules

    register_allorules()


def unregister():
    from allorules.blender import unregister as unregister_allorules

    unregister_allorules()
'''


class BuildError(AllorulesError):
    """The extension cannot be built from what was given."""


@dataclass(frozen=True)
class Wheel:
    path: Path
    name: str          # normalised distribution name
    version: str
    platform_tags: tuple[str, ...]

    @classmethod
    def from_path(cls, path: Path) -> "Wheel":
        parts = path.name[:-len(".whl")].split("-")
        if len(parts) not in (5, 6):
            raise BuildError(f"{path.name}: not a wheel file name (name-version-python-abi-platform.whl)")
        return cls(path, normalise(parts[0]), parts[1], tuple(parts[-1].split(".")))

    def fits(self, platform: str) -> bool:
        return any(tag == "any" or _TAG_PATTERN[platform].match(tag) for tag in self.platform_tags)


def normalise(name: str) -> str:
    """PEP 503 name: ``PyYAML`` and ``pyyaml``, ``fast_simplification`` and ``fast-simplification`` agree."""
    return re.sub(r"[-_.]+", "-", name).lower()


def wheel_requirements(wheel: Path) -> list[str]:
    """The ``Requires-Dist`` lines of a wheel that apply without extras."""
    with zipfile.ZipFile(wheel) as archive:
        name = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        metadata = email.parser.Parser().parsestr(archive.read(name).decode("utf-8"))
    return [line for line in metadata.get_all("Requires-Dist") or [] if "extra ==" not in line]


def requirement_name(requirement: str) -> str:
    return normalise(re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", requirement).group(1))


def manifest_text(version: str, platform: str, wheel_names: list[str]) -> str:
    """``blender_manifest.toml`` (schema 1.0.0) for this build."""
    wheels = ",\n".join(f'  "./wheels/{name}"' for name in wheel_names)
    return f'''schema_version = "1.0.0"

id = "{EXTENSION_ID}"
version = "{version}"
name = "allorules"
tagline = "Scale an animal's mesh the way biology scales animals"
maintainer = "allorules developers"
type = "add-on"
tags = ["Mesh", "Modeling"]
blender_version_min = "{BLENDER_VERSION_MIN}"
license = ["SPDX:MIT"]
platforms = ["{platform}"]
wheels = [
{wheels},
]

[permissions]
files = "Read ruleset files and cache harmonic bases on disk"
'''


def build_extension(wheel_folder: str | Path, output: str | Path, *, platform: str = "linux-x64",
                    require_dependencies: bool = True) -> Path:
    """Write the extension archive ``output`` from the wheels in ``wheel_folder``; return its path.

    The folder must hold exactly one allorules wheel and (with ``require_dependencies``) a wheel
    for every dependency it needs, recursively, except those Blender ships; wheels for another
    platform are refused. Extra wheels in the folder are bundled too.
    """
    if platform not in PLATFORMS:
        raise BuildError(f"unknown platform {platform!r}; choose one of {', '.join(PLATFORMS)}")
    folder = Path(wheel_folder)
    if not folder.is_dir():
        raise BuildError(f"{folder}: no such folder of wheels")
    wheels = [Wheel.from_path(path) for path in sorted(folder.glob("*.whl"))]
    wheels = [wheel for wheel in wheels if wheel.name not in SHIPPED_BY_BLENDER]
    ours = [wheel for wheel in wheels if wheel.name == "allorules"]
    if len(ours) != 1:
        raise BuildError(f"{folder}: needs exactly one allorules wheel (make it with 'pip wheel . --no-deps -w {folder}'), "
                         f"found {len(ours)}")
    names: dict[str, Wheel] = {}
    for wheel in wheels:
        if wheel.name in names:
            raise BuildError(f"{folder}: two wheels of {wheel.name} ({names[wheel.name].path.name}, {wheel.path.name}); keep one")
        if not wheel.fits(platform):
            raise BuildError(f"{wheel.path.name}: built for {'.'.join(wheel.platform_tags)}, not {platform}; "
                             f"fetch the wheels for {platform}")
        names[wheel.name] = wheel
    if require_dependencies:
        missing, seen, queue = set(), set(), [ours[0]]
        while queue:
            wheel = queue.pop()
            for requirement in wheel_requirements(wheel.path):
                if ";" in requirement and "python_version" not in requirement and "sys_platform" not in requirement:
                    continue
                if ";" in requirement and not _marker_holds(requirement.split(";", 1)[1], platform):
                    continue
                name = requirement_name(requirement)
                if name in SHIPPED_BY_BLENDER or name in seen:
                    continue
                seen.add(name)
                if name in names:
                    queue.append(names[name])
                else:
                    missing.add(name)
        if missing:
            raise BuildError(f"{folder}: no wheel for {', '.join(sorted(missing))}; fetch them with "
                             f"'python -m allorules.blender.build --fetch-wheels {folder} --platform {platform}'")
    output = Path(output)
    bundled = sorted(names.values(), key=lambda wheel: wheel.name)
    from allorules.files import atomic_path

    with atomic_path(output) as temporary:
        with zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive:
            archive.writestr("blender_manifest.toml",
                             manifest_text(ours[0].version, platform, [wheel.path.name for wheel in bundled]))
            archive.writestr("__init__.py", INIT_PY)
            for wheel in bundled:   # wheels are zip files already: stored, not compressed again
                archive.write(wheel.path, f"wheels/{wheel.path.name}", compress_type=zipfile.ZIP_STORED)
    return output


def _marker_holds(marker: str, platform: str) -> bool:
    """Evaluate an environment marker for Blender's Python on ``platform`` (packaging if present)."""
    try:
        from packaging.markers import Marker
    except ImportError:      # without packaging: bundle rather than miss a dependency
        return True
    system = {"linux-x64": ("linux", "Linux"), "windows-x64": ("win32", "Windows")}.get(platform, ("darwin", "Darwin"))
    environment = {"python_version": PYTHON_VERSION, "python_full_version": PYTHON_VERSION + ".9",
                   "sys_platform": system[0], "platform_system": system[1], "implementation_name": "cpython",
                   "platform_python_implementation": "CPython", "os_name": "nt" if system[0] == "win32" else "posix",
                   "platform_machine": "arm64" if platform == "macos-arm64" else "x86_64"}
    try:
        return Marker(marker).evaluate(environment)
    except Exception:        # noqa: BLE001 - an odd marker: bundle rather than miss
        return True


def fetch_wheels(folder: str | Path, *, platform: str = "linux-x64", source: str | Path = ".") -> Path:
    """Fill ``folder`` with the allorules wheel (built from ``source``) and its dependencies'
    wheels for ``platform`` and Blender's Python and numpy. Uses pip and the network."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("allorules-*.whl"):
        old.unlink()
    pip = [sys.executable, "-m", "pip"]
    _run([*pip, "wheel", str(source), "--no-deps", "-w", str(folder)])
    ours = next(folder.glob("allorules-*.whl"))
    requirements = [requirement.split(";")[0].strip() if ";" in requirement and not _marker_holds(requirement.split(";", 1)[1], platform)
                    else requirement for requirement in wheel_requirements(ours)]
    requirements = [r for r in requirements if requirement_name(r) not in SHIPPED_BY_BLENDER]
    command = [*pip, "download", "--only-binary=:all:", "--python-version", PYTHON_VERSION, "--implementation", "cp",
               "-d", str(folder)]
    for tag in PLATFORMS[platform]:
        command += ["--platform", tag]
    _run([*command, f"numpy=={BLENDER_NUMPY}", *requirements])
    return folder


def _run(command: list[str]) -> None:
    completed = subprocess.run(command, capture_output=True, text=True)
    if completed.returncode != 0:
        last = (completed.stderr or completed.stdout).strip().splitlines()
        raise BuildError(f"{' '.join(command[:4])} … failed: {last[-1] if last else 'no output'}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m allorules.blender.build", description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", metavar="FILE.zip", help="the extension file to write")
    parser.add_argument("--wheels", metavar="DIR", help="build offline from the wheels in DIR")
    parser.add_argument("--fetch-wheels", metavar="DIR", help="fetch the wheels into DIR (network)")
    parser.add_argument("--platform", default="linux-x64", choices=sorted(PLATFORMS))
    parser.add_argument("--source", default=".", help="the allorules source tree to build the wheel from (default .)")
    arguments = parser.parse_args(argv)
    try:
        if arguments.fetch_wheels:
            fetch_wheels(arguments.fetch_wheels, platform=arguments.platform, source=arguments.source)
            print(f"fetched the wheels for {arguments.platform} into {arguments.fetch_wheels}")
        if arguments.output:
            if arguments.wheels:
                folder = arguments.wheels
                built = build_extension(folder, arguments.output, platform=arguments.platform)
            elif arguments.fetch_wheels:
                built = build_extension(arguments.fetch_wheels, arguments.output, platform=arguments.platform)
            else:
                with tempfile.TemporaryDirectory() as folder:
                    fetch_wheels(folder, platform=arguments.platform, source=arguments.source)
                    built = build_extension(folder, arguments.output, platform=arguments.platform)
            print(f"wrote {built}: install it in Blender from Preferences > Get Extensions > Install from Disk")
        elif not arguments.fetch_wheels:
            parser.error("give -o FILE.zip (and --wheels DIR to build offline), or --fetch-wheels DIR")
    except AllorulesError as error:
        print(f"error: {error}", file=sys.stderr)
        return error.exit_code
    return 0


if __name__ == "__main__":
    sys.exit(main())
