"""``allorules cache``: where the harmonic-basis cache is, how big, how many entries;
``allorules cache clear`` empties it (see the cache section of README.md)."""
from __future__ import annotations

import argparse


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "cache", help=command_help("cache"),
        description="Harmonic bases are cached on disk, keyed by the exact mesh and number of modes, so a "
        "second run on the same mesh skips the eigen-solve. The cache is in ALLORULES_CACHE_DIR (default "
        "~/.cache/allorules/bases; 'off' switches it off) and holds at most ALLORULES_CACHE_MAX bytes (default "
        "2G; the least recently used entries go first). See README.md, 'The basis cache'.")
    parser.add_argument("action", nargs="?", choices=("info", "clear"), default="info",
                        help="info (default): where, how big, how many entries; clear: remove every entry")
    parser.set_defaults(run=run)


def _size(value: int) -> str:
    for unit, scale in (("GB", 1024**3), ("MB", 1024**2), ("kB", 1024)):
        if value >= scale:
            return f"{value / scale:.1f} {unit}"
    return f"{value} bytes"


def run(arguments: argparse.Namespace) -> int:
    from allorules.spectral.cache import cache_info, clear_cache

    info = cache_info()
    if info.directory is None:
        print("the basis cache is off (ALLORULES_CACHE_DIR=off); bases are computed on every run")
        return 0
    if arguments.action == "clear":
        removed, freed = clear_cache()
        left = cache_info()
        print(f"{info.directory}: removed {removed} file{'s' * (removed != 1)} ({_size(freed)})")
        if left.entries or left.temporaries:
            from allorules.errors import AllorulesError

            raise AllorulesError(f"{left.entries + left.temporaries} files in {info.directory} could not be removed; "
                                 "check the folder's permissions")
        return 0
    limit = "no limit" if info.limit is None else f"limit {_size(info.limit)}"
    where = info.directory if info.directory.exists() else f"{info.directory} (not created yet)"
    print(f"basis cache: {where}")
    print(f"  {info.entries} entr{'y' if info.entries == 1 else 'ies'}, {_size(info.bytes)} ({limit}; "
          "ALLORULES_CACHE_MAX changes it)")
    if info.temporaries:
        print(f"  {info.temporaries} temporary file{'s' * (info.temporaries != 1)} (writes in progress, or left by "
              "a run that was killed: removed after an hour, or by 'allorules cache clear')")
    return 0
