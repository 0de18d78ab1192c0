"""The `condor` command line: one subcommand per stage, each a thin call into the library."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from condor.scenes import PRESETS, get_scene


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0 or value >= 2**63:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2**63), got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def _scene_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="default", choices=sorted(PRESETS),
                        help="scene preset: box, depth, pixels (default: %(default)s)")


def cmd_mould(args) -> None:
    from condor.moulds import MouldParams, draw_mould, generate_mould, save_json, validate_mould

    scene = get_scene(args.scene)
    params = MouldParams(no_tether_fraction=args.no_tether_fraction)
    params.validate()
    mould = generate_mould(args.seed, args.id, box=scene.box, params=params,
                           area_fraction=scene.area_fraction, max_extent=scene.max_extent)
    validate_mould(mould)
    if args.out:
        save_json(mould, args.out)
    if args.png:
        from condor.figures import _pyplot

        plt = _pyplot()
        fig, ax = plt.subplots(figsize=(4, 4))
        draw_mould(ax, mould)
        fig.savefig(args.png, dpi=120, bbox_inches="tight")
        plt.close(fig)
    print(f"mould {mould.mould_id} (seed {mould.seed}): {mould.symmetry}, order {mould.order}, "
          f"removal {mould.removal}, {mould.n_tethers} tethers, box {mould.box:g} l0")


def cmd_simulate(args) -> None:
    from condor.moulds import load_json
    from condor.simulate import simulate

    scene = get_scene(args.scene)
    mould = load_json(args.mould)
    if abs(mould.box - scene.box) > 1e-9:
        raise CLIError(f"{args.mould} was generated for a {mould.box:g} l0 box, scene "
                       f"{scene.name!r} has {scene.box:g} l0: pass the matching --scene")
    result = simulate(mould.polygon, mould.tethers, scene.depth, solver=args.solver,
                      budget=args.budget, seed=args.seed)
    result.save(args.out)
    print(f"{args.out}: {result.status}; {result.n_cells} cells, energy/cell "
          f"{result.energy_per_cell:.6g}, {result.seconds:.2f} s ({result.solver})")
    if result.status != "ok":
        sys.exit(1)


def cmd_rasterise(args) -> None:
    import numpy as np

    from condor.pipeline import rasterise_result
    from condor.simulate import SimResult

    scene = get_scene(args.scene)
    result = SimResult.load(args.simulation)
    if result.status != "ok":
        raise CLIError(f"{args.simulation} is a failed simulation ({result.status}); no fields")
    fields = rasterise_result(result, scene)
    out = Path(args.out)
    if out.suffix == ".npy":
        np.save(out, fields)
    elif out.suffix == ".png":
        from condor.fields import FIELD_NAMES
        from condor.figures import _pyplot

        plt = _pyplot()
        fig, axes = plt.subplots(2, 4, figsize=(10, 5))
        for ax, name, image in zip(axes.ravel(), FIELD_NAMES, fields):
            fig.colorbar(ax.imshow(image, origin="lower"), ax=ax, fraction=0.046)
            ax.set_title(name)
            ax.set_xticks([])
            ax.set_yticks([])
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
    else:
        raise CLIError(f"--out must end in .npy or .png, got {out}")
    print(f"{out}: 8 fields at {scene.pixels} px from {result.n_cells} cells")


def cmd_check_store(args) -> None:
    from condor.store import check_store

    table = check_store(args.store, deep=args.deep)
    counts = table["state"].value_counts()
    print(f"{args.store}: {len(table)} samples: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for state in ("missing", "pending", "failed", "corrupt"):
        rows = table[table["state"] == state]
        if len(rows):
            shown = ", ".join(str(s) for s in rows["sample"].head(20))
            more = f" (+{len(rows) - 20} more)" if len(rows) > 20 else ""
            print(f"  {state}: {shown}{more}")
            if state == "failed":
                for reason, group in rows.groupby("status"):
                    print(f"    {len(group)} x {reason}")
    if (table["state"] != "ok").any():
        sys.exit(1)


def _open_store(path):
    from condor.store import open_dataset

    return open_dataset(path)


def cmd_train(args) -> None:
    from condor.surrogate.train import train
    from condor.surrogate.variants import train_config

    ds = _open_store(args.store)
    settings = {"model": args.model, "base": args.base, "depth": args.depth, "epochs": args.epochs,
                "batch_size": args.batch_size, "lr": args.lr, "lam": args.lam, "seed": args.seed,
                "prediction_mode": args.prediction_mode, "num_threads": args.threads,
                "max_val_samples": args.max_val_samples}
    cfg = train_config(settings, int(ds.sizes["x"]))
    checkpoint = Path(args.checkpoint)
    if args.fresh and checkpoint.exists():
        checkpoint.unlink()
    action = "resuming from" if checkpoint.exists() else "writing"
    print(f"training {cfg.model} on {args.store} ({ds.sizes['x']} px), {action} {checkpoint}",
          flush=True)
    history = train(ds, cfg, checkpoint, device=args.device,
                    log=lambda line: print(line, flush=True))
    seconds = sum(r["seconds"] for r in history)
    print(f"{checkpoint}: {len(history)} epochs, {seconds:.1f} s in all")


def cmd_evaluate(args) -> None:
    from condor.surrogate.checkpoint import load_checkpoint
    from condor.surrogate.evaluate import evaluate, format_correlations, format_summary

    load_checkpoint(args.checkpoint)  # a missing checkpoint is reported before the store is read
    ds = _open_store(args.store)
    result = evaluate(args.checkpoint, ds, out_dir=args.out, split=args.split,
                      modes=args.modes or None, baselines=not args.no_baselines,
                      device=args.device)
    summary = result["summary"]
    print(f"{args.split} split, {len(next(iter(result['evaluations'].values())).mae)} moulds; "
          "mean MAE per field (physical units):")
    print(format_summary(summary))
    print("Pearson r of whole-mould statistics, simulation vs prediction:")
    print(format_correlations(summary))
    print(f"tables and figures in {args.out}")


def cmd_predict(args) -> None:
    from condor.surrogate.predict import Predictor, write_prediction

    predictor = Predictor(args.checkpoint, device=args.device, mode=args.mode)
    inputs, prediction = predictor.predict_file(args.mould)  # a JSON's N_c: its lattice count
    write_prediction(args.out, prediction, inputs, predictor.pixel_size,
                     {"checkpoint": str(args.checkpoint), "mould": str(args.mould),
                      "mode": predictor.mode})
    print(f"{args.out}: 8 fields at {predictor.native} px, predicted N_c = "
          f"{prediction.n_cells:.1f} ({predictor.mode} mode)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="condor", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("mould", help="generate one mould: geometry JSON and a picture")
    p.add_argument("--seed", type=_non_negative_int, required=True, help="global seed")
    p.add_argument("--id", type=_non_negative_int, default=0, help="mould id (default 0)")
    p.add_argument("--out", help="write the geometry as JSON here")
    p.add_argument("--png", help="write a picture here")
    p.add_argument("--no-tether-fraction", type=float, default=100 / 6500,
                   help="share of moulds generated with no tethers (default: the paper's 100/6500)")
    _scene_arg(p)
    p.set_defaults(func=cmd_mould)

    p = sub.add_parser("simulate", help="simulate one mould (JSON from `condor mould`)")
    p.add_argument("mould", help="mould JSON")
    p.add_argument("--out", required=True, help="result file (.npz)")
    p.add_argument("--solver", default="hybrid", choices=["anneal", "minimise", "hybrid"])
    p.add_argument("--budget", type=_positive_float, default=None,
                   help="solver budget (anneal: moves per cell); default: the solver's own")
    p.add_argument("--seed", type=_non_negative_int, default=0, help="simulation seed")
    _scene_arg(p)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("rasterise", help="one simulation result to the 8 fields (.npy or .png)")
    p.add_argument("simulation", help="result file from `condor simulate`")
    p.add_argument("--out", required=True, help="fields.npy (8, y, x) or fields.png")
    _scene_arg(p)
    p.set_defaults(func=cmd_rasterise)

    p = sub.add_parser("check-store", help="list missing, pending, failed and corrupt samples")
    p.add_argument("store", nargs="?", default="results/dataset.zarr")
    p.add_argument("--deep", action="store_true", help="also decode every finished sample's fields")
    p.set_defaults(func=cmd_check_store)
    _surrogate_parsers(sub)
    return parser


def _device_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default=None,
                        help="torch device, e.g. cpu or cuda (default: CUDA when present)")


# condor.surrogate's MODEL_KINDS and PREDICTION_MODES, spelled out so that the parser does
# not import torch (tests/test_cli_surrogate.py checks they agree).
MODEL_KINDS = ("pix2pix", "unet_gan", "unet_l1", "unet")
PREDICTION_MODES = ("eval", "batch_stats", "train")


def _surrogate_parsers(sub) -> None:
    p = sub.add_parser("train", help="train a surrogate on a dataset store (resumes a checkpoint)")
    p.add_argument("--store", required=True, help="dataset store (.zarr) from the workflow")
    p.add_argument("--checkpoint", required=True, help="checkpoint file (.pt); resumed if present")
    p.add_argument("--model", default="unet_l1", choices=MODEL_KINDS,
                   help="pix2pix (the paper's, 256 px), unet_gan, unet_l1 or unet (default: %(default)s)")
    p.add_argument("--epochs", type=_non_negative_int, default=None, help="epochs in all (default 10)")
    p.add_argument("--batch-size", type=_non_negative_int, default=None, help="default 1 (the paper's)")
    p.add_argument("--lr", type=_positive_float, default=None, help="Adam learning rate (default 2e-4)")
    p.add_argument("--lam", type=_positive_float, default=None, help="L1 weight of GAN models (1000)")
    p.add_argument("--base", type=_non_negative_int, default=None, help="U-Net first-level width (32)")
    p.add_argument("--depth", type=_non_negative_int, default=None,
                   help="U-Net levels (default: down to a 4x4 bottleneck)")
    p.add_argument("--seed", type=_non_negative_int, default=None, help="training seed (0)")
    p.add_argument("--prediction-mode", default=None, choices=PREDICTION_MODES,
                   help="BatchNorm/dropout mode for validation and prediction (eval)")
    p.add_argument("--max-val-samples", type=_non_negative_int, default=None,
                   help="validate on at most this many samples (default: all)")
    p.add_argument("--threads", type=_non_negative_int, default=None,
                   help="torch CPU threads (default 1)")
    p.add_argument("--fresh", action="store_true", help="delete the checkpoint and start over")
    _device_arg(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help="test-split metrics, figures and baselines of a checkpoint")
    p.add_argument("--store", required=True, help="dataset store (.zarr)")
    p.add_argument("--checkpoint", required=True, help="checkpoint from `condor train`")
    p.add_argument("--out", required=True, help="folder for the CSV tables and PNG figures")
    p.add_argument("--split", default="test", choices=["train", "val", "test"])
    p.add_argument("--modes", nargs="+", choices=PREDICTION_MODES, default=None,
                   help="prediction modes to evaluate (default: the checkpoint's and train)")
    p.add_argument("--no-baselines", action="store_true", help="skip the baselines")
    _device_arg(p)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("predict", help="predict the 8 fields of one mould with a checkpoint")
    p.add_argument("mould", help="mould JSON from `condor mould`, or (2, H, W) .npy / 2-channel .png")
    p.add_argument("--checkpoint", required=True, help="checkpoint from `condor train`")
    p.add_argument("--out", required=True, help="fields.zarr (raw and normalised) or fields.png")
    p.add_argument("--mode", default=None, choices=PREDICTION_MODES,
                   help="BatchNorm/dropout mode (default: the checkpoint's)")
    _device_arg(p)
    p.set_defaults(func=cmd_predict)


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except CLIError as err:
        print(f"condor {args.command}: error: {err}", file=sys.stderr)
        sys.exit(2)
    except (ValueError, OSError, RuntimeError) as err:
        # Library errors name the bad value; print them as one line, not a traceback.
        print(f"condor {args.command}: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
