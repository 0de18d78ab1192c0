"""The `condor` command line: one subcommand per stage, each a thin call into the stage layer
(condor.stages) or the library. User errors print one line and exit with status 2; nothing
that exists is overwritten without --force."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from condor.completion import completion_script
from condor.data.store import SPLITS
from condor.files import WriteError, fault_message, write_fault
from condor.model.scenes import PRESETS, get_scene
from condor.model.simulate import DEFAULT_SOLVER, SOLVERS
from condor.moulds.composite import COMPOSITE
from condor.moulds.lab import FAMILY_NAMES
from condor.moulds.mould import PAPER
from condor.moulds.paper import MouldParams
from condor.moulds.place import FIT_MODES
from condor.moulds.read import load_placement
from condor.moulds.read_picture import POST_MODES, PictureOptions
from condor.moulds.units import UNITS
from condor.surrogate.modes import AUTO_PRECISION, DEFAULT_PRECISION, PRECISIONS, PREDICTION_MODES


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


class Parser(argparse.ArgumentParser):
    """argparse's parser, whose errors suggest the nearest subcommand, choice or flag
    (difflib; argparse's own suggest_on_error needs Python 3.14)."""

    def parse_args(self, args=None, namespace=None):
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            child = self._command_parser(namespace)
            hint = (child or self)._suggest_flags(extras)
            (child or self).error(f"unrecognized arguments: {' '.join(extras)}{hint}")
        return namespace

    def _command_parser(self, namespace):
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return action.choices.get(getattr(namespace, action.dest, None))
        return None

    def _suggest_flags(self, extras) -> str:
        import difflib

        flags = [o for a in self._actions for o in a.option_strings]
        hints = []
        for word in extras:
            if word.startswith("-"):
                near = difflib.get_close_matches(word.split("=")[0], flags, n=1, cutoff=0.6)
                if near:
                    hints.append(f"{word}: did you mean {near[0]}?")
        return f" ({'; '.join(hints)})" if hints else ""

    def error(self, message):
        import difflib
        import re

        match = re.search(r"invalid choice: '([^']*)'", message)
        if match:
            choices = [str(c) for a in self._actions if a.choices for c in a.choices]
            near = difflib.get_close_matches(match.group(1), choices, n=1, cutoff=0.5)
            if near:
                message += f" (did you mean {near[0]!r}?)"
        super().error(message)


# --- what an argument may be -------------------------------------------------------------------

def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0 or value >= 2**63:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2**63), got {value}")
    return value


def _check_arg(text: str):
    """--check: a number of simulations, or 'auto' (condor.stages.check.AUTO)."""
    from condor.stages.check import AUTO

    if text == AUTO:
        return AUTO
    try:
        return _non_negative_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a number of simulations (0: none) or "
                                         f"{AUTO!r}, got {text!r}") from None


def _positive_int(text: str) -> int:
    value = _non_negative_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def _new_output(path, force: bool, what: str = "--out") -> Path:
    """`path` as an output: CLIError when it exists and --force is not given."""
    path = Path(path)
    if path.exists() and not force:
        raise CLIError(f"{what} {str(path)!r} exists; pass --force to overwrite it")
    if path.parent != Path("") and not path.parent.is_dir():
        raise CLIError(f"{what} {str(path)!r}: folder {str(path.parent)!r} does not exist")
    return path


def _load_placement(args, scene, path=None):
    """A mould from the generator's JSON, a minimal JSON, an SVG or a DXF (condor.moulds.read),
    with its placement (how its units were read, its scale factor) printed."""
    path = args.mould if path is None else path
    placement = load_placement(path, scene, l0_um=args.l0_um, fit=args.fit, units=args.units,
                               picture=_picture_options(args))
    print(f"{path}: {placement.describe()}", flush=True)
    return placement


def _picture_options(args) -> PictureOptions:
    """How a picture of a mould is read: --invert, --posts, --pixel-um."""
    return PictureOptions(invert=args.invert, posts=args.posts, pixel_um=args.pixel_um)


def _schema_default(section: str, key: str):
    """The workflow config's default of `section/key` (the packaged schema, its only home)."""
    from condor.config import load_schema

    return load_schema()["properties"][section]["properties"][key]["default"]


# --- the commands: each turns its arguments into values and calls one stage ---------------------

def cmd_mould(args) -> None:
    from condor.stages.build import mould_files

    params = MouldParams() if args.no_tether_fraction is None else \
        MouldParams(no_tether_fraction=args.no_tether_fraction)
    params.validate()
    out = _new_output(args.out, args.force) if args.out else None
    png = _new_output(args.png, args.force, "--png") if args.png else None
    mould = mould_files(get_scene(args.scene), args.seed, args.id, params, out, png,
                        args.family)
    if mould.family == PAPER:
        print(f"mould {mould.mould_id} (seed {mould.seed}): {mould.symmetry}, order "
              f"{mould.order}, removal {mould.removal}, {mould.n_tethers} tethers, box "
              f"{mould.box:g} l0")
    else:
        print(f"mould {mould.mould_id} (seed {mould.seed}): lab family {mould.family}, area "
              f"{mould.polygon.area / mould.box ** 2:.3g} of the box, "
              f"{len(mould.polygon.interiors)} holes, {mould.n_tethers} posts, box "
              f"{mould.box:g} l0")


def cmd_simulate(args) -> None:
    from condor.stages.build import simulate_placed

    scene = get_scene(args.scene)
    out = _new_output(args.out, args.force)
    import pandas as pd

    from condor.surrogate.answer import format_mould_summary

    result = simulate_placed(_load_placement(args, scene), scene, args.solver, args.budget,
                             args.seed, out)
    print(f"{out}: {result.status}; {result.n_cells} cells, energy/cell "
          f"{result.energy_per_cell:.6g}, {result.seconds:.2f} s ({result.solver})")
    if result.status != "ok":
        sys.exit(1)
    table = pd.DataFrame([{"statistic": name, "value": entry["value"], "spread": float("nan"),
                           "unit": entry["unit"]}
                          for name, entry in result.info["statistics"].items()])
    print(f"whole-mould statistics, simulated (one simulation, seed {args.seed}; as condor "
          "predict names them):")
    print(format_mould_summary(table))


def cmd_rasterise(args) -> None:
    from condor.stages.build import rasterise_file

    out = Path(args.out)
    if out.suffix not in (".npy", ".png"):
        raise CLIError(f"--out must end in .npy or .png, got {out}")
    _new_output(out, args.force)
    result, scene = rasterise_file(args.simulation, args.scene, out)
    print(f"{out}: 8 fields at {scene.pixels} px (scene {scene.name!r}) from {result.n_cells} cells")


def cmd_check_store(args) -> None:
    from condor.stages.build import store_report

    lines, whole = store_report(args.store, deep=args.deep)
    print("\n".join(lines))
    if not whole:
        sys.exit(1)


def _settings(args) -> tuple[str, dict]:
    """The variant to train and its flat settings: the preset (or the --config's variant,
    layered over its preset as the workflow layers it), with what --set and the flags change."""
    import yaml

    from condor.surrogate.variants import resolve

    models, threads = {}, None
    if args.config:
        from condor.config import Config

        config = Config.load(*args.config)
        models, threads = config.to_dict()["surrogate"]["models"], config.surrogate["threads"]
    name = args.variant or (_schema_default("surrogate", "variants")[0] if not args.config
                            else config.surrogate["variants"][0])
    settings = resolve(name, models)
    for item in args.set or ():
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CLIError(f"--set {item!r}: expected KEY=VALUE, e.g. --set epochs=5")
        settings[key.strip()] = yaml.safe_load(value)
    flags = {"base": args.base, "depth": args.depth, "epochs": args.epochs,
             "batch_size": args.batch_size, "lr": args.lr, "lam": args.lam, "seed": args.seed,
             "prediction_mode": args.prediction_mode, "max_val_samples": args.max_val_samples}
    settings.update({k: v for k, v in flags.items() if v is not None})
    if args.threads is None and threads is not None:
        args.threads = threads  # the workflow's threads a training job: the same numbers
    return name, settings


def cmd_train(args) -> None:
    from condor.stages.surrogate import train_variant

    name, settings = _settings(args)
    checkpoint = Path(args.checkpoint)
    if checkpoint.exists() and not checkpoint.is_dir() and not args.force:
        raise CLIError(f"--checkpoint {str(checkpoint)!r} exists; pass --force to replace it "
                       "(or choose another file)")
    print(f"training {name} ({settings['model']}) on {args.store} into {args.checkpoint}",
          flush=True)
    history = train_variant(args.store, settings, args.checkpoint, threads=args.threads,
                            device=args.device, fresh=args.fresh, restart_on_mismatch=False,
                            log_line=lambda line: print(line, flush=True))
    seconds = sum(r["seconds"] for r in history)
    print(f"{args.checkpoint}: {len(history)} epochs, {seconds:.1f} s in all")


def cmd_evaluate(args) -> None:
    from condor.stages.surrogate import evaluate_variant
    from condor.surrogate.evaluate import format_correlations, format_evaluation

    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise CLIError(f"--out {str(out)!r} holds files; pass --force to overwrite them")
    result = evaluate_variant(args.store, args.checkpoint, out, modes=args.modes or None,
                              device=args.device, baselines=not args.no_baselines,
                              split=args.split)
    summary = result["summary"]
    print(f"{args.split} split, {len(next(iter(result['evaluations'].values())).mae)} moulds; "
          "mean MAE per field:")
    print(format_evaluation(summary))
    print("Pearson r of whole-mould statistics, simulation vs prediction:")
    print(format_correlations(summary))
    print(f"tables and figures in {out}")


def cmd_predict(args) -> None:
    from condor.stages.predict import predict_mould

    result = predict_mould(args.checkpoint, args.mould, args.out, l0_um=args.l0_um, fit=args.fit,
                           units=args.units, device=args.device, mode=args.mode,
                           precision=args.precision, force=args.force, check=args.check,
                           picture=_picture_options(args),
                           say=lambda line: print(line, flush=True),
                           warn=lambda line: print(f"condor predict: warning: {line}",
                                                   file=sys.stderr))
    print("\n".join(result.lines()))


def cmd_design(args) -> None:
    from condor.design import parse_objective
    from condor.stages.design import checkpoint_design_scene, design, summary_lines

    parse_objective(args.objective)  # a bad objective is named before anything is loaded
    scene = checkpoint_design_scene(args.checkpoint)
    placements = [_load_placement(args, scene, path) for path in args.mould or ()]
    yours = [placement.mould for placement in placements]
    keep = tuple(k for k in (args.keep or "").split(",") if k)
    if keep and not yours:
        raise CLIError(f"--keep {args.keep} constrains the search to your mould: give it with "
                       "--mould")
    summary = design(scene, args.checkpoint, args.out, args.objective, budget=args.budget,
                     seed=args.seed, n_top=args.top, n_random=args.random,
                     replicas=args.replicas, store=args.store, l0_um=args.l0_um,
                     your_moulds=yours, force=args.force, keep=keep,
                     fit_scale=placements[0].scale if placements else 1.0,
                     say=lambda line: print(f"condor design: {line}", file=sys.stderr,
                                            flush=True)).iloc[0]
    print("\n".join(summary_lines(summary, args.out, args.top, args.objective, args.store,
                                  args.mould or ())))


def cmd_completion(args) -> None:
    sys.stdout.write(completion_script(build_parser()))


# --- the parser: one function a subcommand ------------------------------------------------------

def _scene_arg(parser: argparse.ArgumentParser, default="default", unset: str = "") -> None:
    parser.add_argument("--scene", default=default, choices=sorted(PRESETS),
                        help="scene preset: box, depth, pixels (default: "
                             + (unset if default is None else "%(default)s") + ")")


def _force_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")


def _device_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default=None,
                        help="torch device, e.g. cpu or cuda (default: CUDA when present)")


def _windows(l0_um: float = 16.0) -> str:
    """Each scene's window (its square box) in mm at cell spacing `l0_um`."""
    return ", ".join(f"{name} {scene.box * l0_um / 1000:.3g} mm"
                     for name, scene in sorted(PRESETS.items(), key=lambda kv: kv[1].box))


def _user_mould_args(parser: argparse.ArgumentParser) -> None:
    scene = get_scene("default")  # every preset's area fraction and largest extent
    parser.add_argument("--l0-um", type=_positive_float, default=None,
                        help="cell spacing l0 in micrometres, for a drawing in mm or um (and "
                             "drawings written in mm too). A scene's window is its box in l0 "
                             f"times l0: at --l0-um 16, {_windows(16.0)} square (a drawing "
                             "larger than that needs --fit)")
    parser.add_argument("--units", choices=UNITS, default=None,
                        help="units of a drawing that does not state its own (an SVG without "
                             "them is read as CSS px, 96 px an inch)")
    parser.add_argument("--fit", nargs="?", const="area", default=None, choices=FIT_MODES,
                        help="scale the drawing, keeping its aspect ratio: --fit extent makes "
                             f"its larger side {scene.max_extent:g} of the window (the training "
                             "moulds' largest); --fit (or --fit area) makes its area the "
                             f"training moulds' ({100 * scene.area_fraction:g}%% of the box), "
                             "capped by the extent fit. The scale factor is printed and "
                             "recorded. Default: keep the drawn size")
    parser.add_argument("--pixel-um", type=_positive_float, default=None,
                        help="a picture's pixel size in micrometres (with --l0-um); default: "
                             "the picture states it (condor's own) or its larger side spans "
                             "the scene's box")
    parser.add_argument("--posts", default="auto", choices=POST_MODES,
                        help="which regions of a picture are posts: auto (default) the round "
                             "regions of a third shade inside the mould, else its small round "
                             "holes; dark or light: the round regions darker or lighter than "
                             "the mould; holes: every round hole; none: no posts")
    parser.add_argument("--invert", action="store_true",
                        help="a picture's mould is the shade at its edge (e.g. a picture inside "
                             "a frame): by default the background is the edge's shade")


def _parser_completion(sub) -> None:
    p = sub.add_parser("completion", help="print a bash completion script: "
                       "eval \"$(condor completion)\" (or save it in "
                       "~/.local/share/bash-completion/completions/condor)")
    p.set_defaults(func=cmd_completion)


def _parser_mould(sub) -> None:
    p = sub.add_parser("mould", help="generate one mould: geometry JSON and a picture")
    p.add_argument("--seed", type=_non_negative_int, required=True, help="global seed")
    p.add_argument("--id", type=_non_negative_int, default=0, help="mould id (default 0)")
    p.add_argument("--family", default=PAPER, choices=(PAPER,) + FAMILY_NAMES + (COMPOSITE,),
                   help="the paper's generator (default), a lab family or composite "
                        "(docs/moulds.md, \"Lab families\", \"Composite moulds\")")
    p.add_argument("--out", help="write the geometry as JSON here")
    p.add_argument("--png", help="write a picture here")
    p.add_argument("--no-tether-fraction", type=float, default=None,
                   help="share of moulds generated with no tethers (default: the workflow's, "
                        "the paper's 100 in 6,500)")
    _scene_arg(p)
    _force_arg(p)
    p.set_defaults(func=cmd_mould)


def _parser_simulate(sub) -> None:
    p = sub.add_parser("simulate", help="simulate one mould (JSON, SVG or DXF)")
    p.add_argument("mould", help="mould: the generator's JSON, a minimal JSON (outline and "
                   "tethers), an SVG or a DXF drawing, or a picture of the mould (PNG, TIFF, "
                   "JPEG) (docs/user_moulds.md)")
    p.add_argument("--out", required=True, help="result file (.npz)")
    p.add_argument("--solver", default=None, choices=list(SOLVERS),
                   help=f"default: the simulator's ({DEFAULT_SOLVER})")
    p.add_argument("--budget", type=_positive_float, default=None,
                   help="solver budget (anneal: moves per cell); default: the solver's own "
                        "for the scene's box (condor.model.simulate.default_budget)")
    p.add_argument("--seed", type=_non_negative_int, default=0, help="simulation seed")
    _scene_arg(p)
    _user_mould_args(p)
    _force_arg(p)
    p.set_defaults(func=cmd_simulate)


def _parser_rasterise(sub) -> None:
    p = sub.add_parser("rasterise", help="one simulation result to the 8 fields (.npy or .png)")
    p.add_argument("simulation", help="result file from `condor simulate`")
    p.add_argument("--out", required=True, help="fields.npy (8, y, x) or fields.png")
    _scene_arg(p, default=None, unset="the scene the simulation records, else default")
    _force_arg(p)
    p.set_defaults(func=cmd_rasterise)


def _parser_check_store(sub) -> None:
    p = sub.add_parser("check-store", help="list missing, pending, failed and corrupt samples")
    p.add_argument("store", nargs="?", default="results/dataset.zarr",
                   help="the dataset store to check (default: %(default)s)")
    p.add_argument("--deep", action="store_true",
                   help="also decode every chunk of every array (checksums, NaN) and move the "
                   "damaged ones aside, to <store>.damaged/, for the next run to rebuild")
    p.set_defaults(func=cmd_check_store)


def _parser_train(sub) -> None:
    p = sub.add_parser("train", help="train a surrogate variant on a dataset store (an "
                       "interrupted run resumes); a flag left out takes the variant's setting")
    p.add_argument("--store", required=True, help="dataset store (.zarr) from the workflow")
    p.add_argument("--checkpoint", required=True, help="checkpoint file (.pt) to write; an "
                   "interrupted run of the same settings and data resumes from "
                   ".NAME.training.pt beside it")
    p.add_argument("--variant", default=None,
                   help="a preset of condor.surrogate.variants.PRESETS (unet, unet_l1, unet_gan, "
                        "pix2pix) or a variant of --config (default: the workflow's, the first "
                        "of surrogate/variants)")
    p.add_argument("--config", nargs="+", default=None, metavar="YAML",
                   help="workflow config file(s), layered as Snakemake layers them, whose "
                        "surrogate/models define or change the variant and whose "
                        "surrogate/threads is the default --threads (e.g. config/tiny.yaml: "
                        "the tiny workflow's model, bit for bit)")
    p.add_argument("--set", action="append", default=None, metavar="KEY=VALUE",
                   help="change any setting of the variant (condor.surrogate.variants."
                        "SETTING_KEYS; VALUE in YAML, e.g. --set betas=[0.9,0.99]); repeatable")
    p.add_argument("--epochs", type=_positive_int, default=None, help="epochs in all")
    p.add_argument("--batch-size", type=_positive_int, default=None)
    p.add_argument("--lr", type=_positive_float, default=None, help="Adam learning rate")
    p.add_argument("--lam", type=_positive_float, default=None, help="L1 weight of GAN models")
    p.add_argument("--base", type=_positive_int, default=None, help="U-Net first-level width")
    p.add_argument("--depth", type=_positive_int, default=None, help="U-Net levels")
    p.add_argument("--seed", type=_non_negative_int, default=None, help="training seed")
    p.add_argument("--prediction-mode", default=None, choices=PREDICTION_MODES,
                   help="BatchNorm/dropout mode for validation and prediction")
    p.add_argument("--max-val-samples", type=_positive_int, default=None,
                   help="validate on at most this many samples")
    p.add_argument("--threads", type=_positive_int, default=None,
                   help="torch CPU threads (default: --config's surrogate/threads, else 1)")
    p.add_argument("--fresh", action="store_true", help="discard the epochs of an interrupted "
                   "run and start over")
    _device_arg(p)
    _force_arg(p)
    p.set_defaults(func=cmd_train)


def _parser_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="test-split metrics, figures and baselines of a checkpoint")
    p.add_argument("--store", required=True, help="dataset store (.zarr)")
    p.add_argument("--checkpoint", required=True, help="checkpoint from `condor train`")
    p.add_argument("--out", required=True, help="folder for the CSV tables and PNG figures")
    p.add_argument("--split", default="test", choices=SPLITS,
                   help="the split whose moulds are scored (default: %(default)s)")
    p.add_argument("--modes", nargs="+", choices=PREDICTION_MODES, default=None,
                   help="prediction modes to evaluate (default: the checkpoint's and train)")
    p.add_argument("--no-baselines", action="store_true", help="skip the baselines")
    _device_arg(p)
    _force_arg(p)
    p.set_defaults(func=cmd_evaluate)


def _parser_predict(sub) -> None:
    p = sub.add_parser("predict", help="predict the 8 fields of one mould with a checkpoint")
    p.add_argument("mould", help="mould: JSON, SVG, DXF or a picture of it (PNG, TIFF, JPEG), "
                   "as for simulate; or its input channels as a (2, H, W) 0/1 .npy")
    p.add_argument("--checkpoint", required=True, help="checkpoint from `condor train`")
    p.add_argument("--out", required=True, help="fields.zarr (raw and normalised) or fields.png")
    p.add_argument("--mode", default=None, choices=PREDICTION_MODES,
                   help="BatchNorm/dropout mode (default: the checkpoint's)")
    p.add_argument("--precision", default=DEFAULT_PRECISION,
                   choices=(AUTO_PRECISION,) + PRECISIONS,
                   help="the network's arithmetic: bfloat16 is about twice as fast where the "
                        "CPU has it and moves the fields by a few 1e-3 of their largest value; "
                        "auto takes it where it is native (default: %(default)s)")
    p.add_argument("--check", type=_check_arg, default="auto", metavar="N",
                   help="simulate the mould N times with the dataset's solver and score the "
                        "prediction against them; the answer written is then the prediction "
                        "and their mean weighed by their measured errors, the surrogate's own "
                        "kept beside it (N >= 2; 0: no check, the surrogate's answer). "
                        "Default auto: 4 simulations where the mould holds at most "
                        "4,000 cells (the default and tiny scenes: seconds in all), none at the "
                        "paper scene")
    _user_mould_args(p)
    _device_arg(p)
    _force_arg(p)
    p.set_defaults(func=cmd_predict)


def _parser_design(sub) -> None:
    p = sub.add_parser("design", help="search moulds for an objective with a surrogate, confirm "
                       "by simulation, write drawings")
    p.add_argument("--objective", required=True,
                   help="what to maximise, e.g. alignment:x, uniformity, -max_tension, "
                        "alignment:45deg@disc(0.5,0.5,0.2)+0.5*uniformity; docs/design.md")
    p.add_argument("--checkpoint", required=True, help="surrogate checkpoint (its scene is used)")
    p.add_argument("--out", required=True, help="folder for designs.csv, drawings, predictions")
    design = {key: _schema_default("design", key)  # the workflow's defaults, one home
              for key in ("budget", "top", "random", "replicas", "seed")}
    p.add_argument("--budget", type=_positive_int, default=design["budget"],
                   help="designs the surrogate scores (default: %(default)s)")
    p.add_argument("--top", type=_positive_int, default=design["top"],
                   help="best designs confirmed and drawn (default: %(default)s)")
    p.add_argument("--random", type=_non_negative_int, default=design["random"],
                   help="random searched designs also confirmed, for the rank correlation "
                        "(default: %(default)s)")
    p.add_argument("--replicas", type=_positive_int, default=design["replicas"],
                   help="simulations per design (default: %(default)s)")
    p.add_argument("--seed", type=_non_negative_int, default=design["seed"],
                   help="search seed (default: %(default)s)")
    p.add_argument("--store", default=None,
                   help="dataset store whose test moulds are the baseline to beat")
    p.add_argument("--mould", action="append", default=None,
                   help="your own mould (JSON, SVG, DXF or a picture; repeat for several): scored, "
                        "predicted and simulated, as the design to beat")
    p.add_argument("--keep", default=None, choices=["footprint", "posts", "footprint,posts",
                                                    "posts,footprint"],
                   metavar="footprint|posts|footprint,posts",
                   help="constrain the search to your (first) mould: footprint keeps its "
                        "outline and searches where its posts go; posts keeps its number of "
                        "posts; footprint,posts both")
    _user_mould_args(p)
    _force_arg(p)
    p.set_defaults(func=cmd_design)


SUBCOMMANDS = (_parser_completion, _parser_mould, _parser_simulate, _parser_rasterise,
               _parser_check_store, _parser_train, _parser_evaluate, _parser_predict,
               _parser_design)


def build_parser() -> argparse.ArgumentParser:
    from condor import __version__

    parser = Parser(prog="condor", description=__doc__)
    parser.add_argument("--version", action="version", version=f"condor {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in SUBCOMMANDS:
        add(sub)
    for action in sub._choices_actions:  # each command's --help opens with its one line
        child = sub.choices[action.dest]
        if child.description is None:
            child.description = action.help
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (CLIError, WriteError) as err:
        _fail(args, err)
    except PermissionError as err:  # a read-only output folder, most often
        where = f": {str(err.filename)!r}" if err.filename else f" ({err})"
        _fail(args, f"permission denied{where} (is the folder read-only?)")
    except (ValueError, OSError, RuntimeError) as err:
        # Library errors name the bad value; print them as one line, not a traceback. A write
        # that failed (disk full, a file-size limit) outside condor.files.atomic_path: its cause
        # in words, and its file where the error names it.
        fault = write_fault(err)
        _fail(args, err if fault is None else fault_message(fault.filename, fault))


def _fail(args, message) -> None:
    """Print `message` as one line (a library's may span several) and exit with status 2."""
    text = " ".join(line.strip() for line in str(message).splitlines() if line.strip())
    print(f"condor {args.command}: error: {text}", file=sys.stderr)
    sys.exit(2)


if __name__ == "__main__":
    main()
