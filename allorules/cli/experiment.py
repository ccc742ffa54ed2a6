"""``allorules experiment {global,local}``: the 1-D experiments with the cosine transform (DCT)
as basis (docs/method.md, "The 1-D experiments")."""
from __future__ import annotations

import argparse
import json
import logging

from allorules.cli.arguments import add_png_argument
from allorules.errors import AllorulesError

log = logging.getLogger("allorules")


class ExperimentError(AllorulesError):
    """Bad experiment parameters."""


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "experiment",
        help=command_help("experiment"),
        description="global: the fitted spectral slope of a 1/f signal moves by exactly α under "
        "the global power law. local: the local power law changes an indicator region without a jump at "
        "its edges, arithmetic scaling jumps. See docs/method.md, 'The 1-D experiments'.",
    )
    parser.add_argument("which", choices=["global", "local"], help="which experiment")
    parser.add_argument("--alpha", type=float, default=None,
                        help="allometric exponent (default 1.8 for global, 0.5 for local)")
    parser.add_argument("--length", type=int, default=1024, help="number of samples (default 1024)")
    parser.add_argument("--beta", type=float, default=1.0, help="amplitude spectrum 1/f^β of the signal (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_png_argument(parser, "the signal before and after, and its spectrum")
    parser.add_argument("--force", action="store_true", help="replace an existing picture")
    parser.add_argument("--json", action="store_true", help="print the numbers as one JSON object")
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    from allorules.files import PNG, Output, check_outputs
    from allorules.spectral.experiments import (
        global_experiment,
        local_experiment,
        plot_global,
        plot_local,
    )

    check_outputs([Output.of(arguments.png, "--png", PNG)], force=arguments.force)
    if arguments.length < 16:
        raise ExperimentError(f"--length must be at least 16, got {arguments.length}")
    if arguments.which == "global":
        alpha = 1.8 if arguments.alpha is None else arguments.alpha
        result = global_experiment(alpha, length=arguments.length, beta=arguments.beta, seed=arguments.seed)
        numbers = result.as_dict()
        text = (f"global: slope {result.before.slope:.6f} -> {result.after.slope:.6f}, "
                f"change {result.slope_change:.12f} (predicted {result.predicted_slope_change:g})")
        plot = plot_global
    else:
        alpha = 0.5 if arguments.alpha is None else arguments.alpha
        if alpha == 0:
            raise ExperimentError("--alpha 0 changes nothing; give a non-zero α")
        result = local_experiment(alpha, length=arguments.length, beta=arguments.beta, seed=arguments.seed)
        numbers = result.as_dict()
        text = (f"local: change inside/outside {result.inside_outside_ratio:.2f}; edge jump power law "
                f"{result.power_law.edge_jump:.4g}, arithmetic {result.arithmetic.edge_jump:.4g} "
                f"({result.jump_ratio:.1f}x)")
        plot = plot_local
    if arguments.png:
        plot(result, arguments.png)
        log.info("wrote %s", arguments.png)
    print(json.dumps(numbers) if arguments.json else text)
    return 0
