"""``styleerd <command>``: argument parsing only; the work lives in the packages."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

from styleerd.atomic import check_output
from styleerd.errors import StyleERDError, unknown_name


def _data_prepare(args: argparse.Namespace) -> None:
    from styleerd.data.cache import FeatureParams, prepare, summary
    from styleerd.data.datasets import DATASETS

    for dataset in args.datasets or DATASETS:
        fs = prepare(
            dataset, args.data, FeatureParams(fps=args.fps), Path(args.cache) if args.cache else None, args.workers
        )
        print(summary(fs))
        print(f"cache: {fs.path}\n")


def _info(args: argparse.Namespace) -> None:
    if args.recalibrate and not args.system:
        raise StyleERDError("info: --recalibrate goes with --system")
    if args.system:
        from styleerd.model.stored import load_generator_weights
        from styleerd.runtime.calibration import STREAMS, engine_settings
        from styleerd.runtime.system import describe, system_report

        model = load_generator_weights(args.model)
        if args.recalibrate:
            from tqdm import tqdm

            with tqdm(total=len(STREAMS), desc="calibrating the numba step", unit="batch size") as bar:
                engine_settings(model, again=True, progress=lambda *_: bar.update())
        print(describe(system_report(model)))
        if not args.file:
            return
    if not args.file:
        raise StyleERDError("info: name a motion or character file, or --system")
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.offline import describe_input

    explicit = _read_joint_map(args.joint_map) if args.joint_map else None
    model = load_generator_weights(args.model)
    if not Path(args.file).is_dir():
        print(describe_input(Path(args.file), model, explicit)[0])
        return
    from styleerd.runtime.batch import MOTION_FILES

    files = sorted(p for p in Path(args.file).rglob("*") if p.suffix.lower() in MOTION_FILES and p.is_file())
    if not files:
        raise StyleERDError(f"{args.file}: no motion files ({', '.join(MOTION_FILES)}) in this folder")
    mapped = unread = 0
    for path in files:  # a file that cannot be read is said and the next one read
        try:
            text, maps = describe_input(path, model, explicit, brief=True)
        except StyleERDError as e:  # its message names the file, mostly
            text, maps, unread = (str(e) if str(e).startswith(str(path)) else f"{path}: {e}"), False, unread + 1
        mapped += maps
        print(text)
    print(f"{len(files)} files: {mapped} map onto the model, {len(files) - mapped - unread} do not, {unread} unread")


def _resample(args: argparse.Namespace) -> None:
    from styleerd.motion import bvh
    from styleerd.motion.gltf import GLTF_INPUTS
    from styleerd.motion.resample import resample

    if not 1 <= args.fps <= 1000:
        raise StyleERDError(f"--fps {args.fps:g} is outside [1, 1000]")
    if Path(args.input).suffix.lower() in (*GLTF_INPUTS, ".fbx"):
        raise StyleERDError(
            f"{args.input}: resample changes a BVH file's frame rate; a glTF, VRM or FBX animation is read at its "
            "own key rate by transfer and info"
        )
    check_output(args.output, args.input)
    m = resample(bvh.read(args.input), args.fps)
    bvh.write(args.output, m)
    print(f"wrote {args.output}: {m.n_frames} frames at {args.fps:g} fps")


def _train(args: argparse.Namespace) -> None:
    from styleerd.train.config import TrainConfig
    from styleerd.train.trainer import train

    config = TrainConfig.from_yaml(args.config, **({"device": args.device} if args.device else {}))
    out = Path(args.out or f"runs/{config.name}")
    best = train(config, out, args.data, export=Path(args.export) if args.export else None)
    print(f"best epoch: {best}")
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        # a torchrun worker leaves now, its run saved: at the interpreter's teardown Gloo's threads
        # can still abort it (SIGABRT after a finished run, 1 CI run in 5; pytorch#179291)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


# Small models trained beside the generator: command -> (help, default output, trainer).
HELPER_MODELS = {
    "train-recognisers": (
        "train the evaluation style/content recognisers",
        "recognisers-bandai2",
        "styleerd.train.trainer:train_recognisers",
    ),
    "train-labeller": (
        "train the online style/content labeller (labels inferred when not given)",
        "labeller-bandai2",
        "styleerd.train.labeller:train_and_save",
    ),
    "train-fmd": (
        "train the FMD feature extractor (denoising autoencoder on joint rotations)",
        "fmd-bandai2",
        "styleerd.train.fmd:train_and_save",
    ),
}


def _train_helper(args: argparse.Namespace) -> None:
    import importlib

    from styleerd.train.config import TrainConfig

    module, function = HELPER_MODELS[args.command][2].split(":")
    config = TrainConfig.from_yaml(args.config) if args.config else TrainConfig()
    report = getattr(importlib.import_module(module), function)(config, args.data, Path(args.out) if args.out else None)
    print(json.dumps(report, indent=1))


def _transfer(args: argparse.Namespace) -> None:
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.batch import batch_pairs, inert_options, transfer_batch, transfer_one
    from styleerd.runtime.offline import TransferOptions
    from styleerd.runtime.stylizer import part_targets, target_weights

    model = load_generator_weights(args.model)
    if args.write_joint_map:
        from styleerd.runtime.offline import write_guessed_joint_map

        if len(args.input) != 1 or Path(args.input[0]).is_dir():
            raise StyleERDError("--write-joint-map: name one motion file")
        guessed, total = write_guessed_joint_map(args.input[0], args.write_joint_map, model)
        print(f"wrote {args.write_joint_map}: {guessed} of {total} model joints guessed; edit it, then --joint-map")
        return
    if not args.output:
        raise StyleERDError("transfer: -o/--output is required")
    c = model.config
    for value, names, what in (
        (args.input_style, c.input_styles, "--input-style"),
        (args.content, c.contents, "--content"),
    ):
        if value is not None and value not in names:
            raise unknown_name(what, value, names)
    target = target_weights(model, args.style, args.intensity, _style_or_mix(args))
    explicit = _read_joint_map(args.joint_map) if args.joint_map else None
    parts = part_targets(model, args.parts)  # checked once here, not once per file
    options = TransferOptions(
        target,
        args.input_style,
        args.content,
        explicit,
        not args.no_cleanup,
        args.backend,
        args.mesh,
        parts or None,
        args.root_speed,
        args.pose,
        args.animation,
        args.keep_original,
    )
    out = Path(args.output)
    if args.onto:
        from styleerd.runtime.offline import transfer_onto

        if len(args.input) != 1 or Path(args.input[0]).is_dir():
            raise StyleERDError("--onto: name one motion file")
        _refuse_inert(inert_options([(Path(args.input[0]), out)], options, onto=True))
        done = transfer_onto(
            Path(args.input[0]), Path(args.onto), out, model, model.meta["data"]["fps"], options, print
        )
        print(
            f"wrote {out}: {done.frames} frames in {done.clips} animation(s) on {Path(args.onto).name}, target {target}"
        )
        return
    into_folder = len(args.input) > 1 or Path(args.input[0]).is_dir() or out.is_dir() or args.output.endswith(os.sep)
    if not into_folder:
        if args.to and out.suffix.lower() != f".{args.to}":
            raise StyleERDError(f"--to {args.to} names the kind of files written into a folder; -o {out} is one file")
        pairs = [(Path(args.input[0]), out)]
    elif out.exists() and not out.is_dir():
        raise StyleERDError(f"-o {out}: several inputs need a folder to write into")
    else:
        pairs = batch_pairs(args.input, out, f".{args.to}" if args.to else None)
    _refuse_inert(inert_options(pairs, options))
    if len(pairs) == 1:  # one file (into a folder or not): no pool, the mapping and labels reported
        (source, output), made = pairs[0], None
        if into_folder and not output.parent.exists():
            made = output.parent
            made.mkdir(parents=True)
        try:
            done = transfer_one(source, output, model, options, report=print)
        except StyleERDError:
            if made is not None:
                made.rmdir()
            raise
        clips = f" in {done.clips} animations" if done.clips > 1 else ""
        print(f"wrote {output}: {done.frames} frames{clips} at {done.fps:.6g} fps, target {target}")
        return
    if not (0 < args.timeout < math.inf) or (args.max_memory is not None and not 0 < args.max_memory < math.inf):
        raise StyleERDError(f"--timeout {args.timeout:g} and --max-memory {args.max_memory} must be positive numbers")
    try:
        failed = transfer_batch(pairs, args.model, options, args.jobs, args.timeout, args.max_memory, args.resume)
    except KeyboardInterrupt:
        print("stopped: every worker ended, no partial file left; --resume goes on where this stopped", file=sys.stderr)
        sys.exit(130)
    print(f"wrote {len(pairs) - len(failed)} of {len(pairs)} files to {out}/, target {target}")
    if failed:
        raise StyleERDError(
            f"{len(failed)} of {len(pairs)} files skipped: "
            + "; ".join(f"{src.name}: {why}" for src, why in failed[:3])
            + (" ..." if len(failed) > 3 else "")
        )


def _style_or_mix(args: argparse.Namespace) -> dict[str, float] | None:
    """``--mix`` read (None where not given), once ``--style`` or ``--mix`` is given, and not both."""
    from styleerd.runtime.stylizer import parse_mix

    mix = parse_mix(args.mix or "")
    if args.style is not None and mix is not None:
        raise StyleERDError(
            f"give --style or --mix, not both: a mixture names each of its styles (--mix {args.style}=0.5,...)"
        )
    if args.style is None and mix is None:
        raise StyleERDError("give --style or --mix")
    return mix


def _refuse_inert(inert: list[str]) -> None:
    if inert:
        raise StyleERDError("changes nothing in this transfer: " + "; ".join(inert))


def _read_joint_map(path: str) -> dict[str, str]:
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise StyleERDError(f"--joint-map {path}: {e}") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise StyleERDError(f"--joint-map {path}: expected a JSON object of model joint -> input joint names")
    return data


def _export_onnx(args: argparse.Namespace) -> None:
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.onnx_export import export

    check_output(args.output)
    model = load_generator_weights(args.model)
    styles = tuple(s.strip() for s in args.styles.split(",")) if args.styles else None
    export(model, args.output, "plain" if args.plain else "lstm", styles)
    print(
        f"wrote {args.output} and {Path(args.output).with_suffix('.json')} (inputs, outputs and features: docs/ONNX.md)"
    )


def _soup(args: argparse.Namespace) -> None:
    from styleerd.train.soup import save_soup

    out = Path(args.output)
    out = out.with_suffix("") if out.suffix in (".safetensors", ".json") else out
    meta = save_soup(args.models, out, args.weights)
    print(f"{meta['training']['kept']}; wrote {out}.safetensors")
    posture = "its posture is the first model's" if "posture" in meta else "it has no posture"
    print(
        f"{posture} and the default familiar range: measure the soup's own with 'styleerd posture {out}' and then "
        f"'styleerd familiar {out}'"
    )


def _measured_into_model(command, name: str, text: str, func) -> argparse.ArgumentParser:
    """A command that measures something of a model and stores it in the model file's configuration."""
    p = command(name, text)
    p.add_argument("model", nargs="?", help=MODEL_HELP)
    p.add_argument("-o", "--output", help="write the model here (no suffix; default: the model file itself)")
    p.add_argument("--data", help="data folder (default: $STYLEERD_DATA, else ../shared/data)")
    p.set_defaults(func=func)
    return p


def _model_to_measure(args: argparse.Namespace):
    """The model a measuring command reads, and where it writes it (``--output``, else the file itself)."""
    from styleerd.model.stored import load_generator_weights, model_stem

    out = Path(args.output).with_suffix("") if args.output else model_stem(args.model)
    check_output(out.with_suffix(".safetensors"))
    return load_generator_weights(args.model), out


def _save_measured(model, out: Path, meta: dict) -> None:
    """The model's weights, unchanged, with ``meta`` as its configuration."""
    import torch

    from styleerd.model.checkpoint import save_tensors

    save_tensors(out, {f"generator.{k}": torch.from_numpy(v) for k, v in model.arrays.items()}, meta)


def _posture(args: argparse.Namespace) -> None:
    import numpy as np

    from styleerd.runtime.posture import measure_posture, training_walks, with_posture

    model, out = _model_to_measure(args)
    walks = list(training_walks(model, args.data))
    if not walks:
        raise StyleERDError(f"no neutral walks in the training split of {model.meta['data']['dataset']}")
    posture = measure_posture(model, walks, args.frame)
    frames = sum(m.n_frames for m, _ in walks)
    _save_measured(model, out, with_posture(model.meta, model, posture, len(walks), frames, args.frame))
    degrees = np.degrees(np.linalg.norm(posture[0], axis=-1))
    moved = np.linalg.norm(posture[1], axis=-1)
    for style, row, far in zip(model.config.styles, degrees, moved):
        if style != model.config.neutral_style:
            top, farthest = np.argsort(row)[::-1][:3], np.argsort(far)[::-1][:3]
            print(
                f"{style}: mean {row.mean():.1f} deg; most: "
                + ", ".join(f"{model.skeleton.names[j]} {row[j]:.0f}" for j in top)
                + "; moved most: "
                + ", ".join(f"{model.skeleton.names[j]} {far[j]:.3g}" for j in farthest)
            )
    print(f"posture of {len(walks)} walks ({frames} frames); wrote {out}.safetensors")


def _familiar(args: argparse.Namespace) -> None:
    from styleerd.eval.actions import familiar_range_for

    model, out = _model_to_measure(args)
    measured = familiar_range_for(model, args.data)
    _save_measured(model, out, {**model.meta, "familiar": measured})
    takes = lambda figures: ", ".join(f"{name} {e:.1f} cm / {c:.2f}" for name, (e, c) in figures.items())
    print(f"the input's own pose: {takes(measured['input'])}")
    for row in measured["tried"]:
        print("{:g}-{:g} deg: ".format(*row["degrees"]) + takes(row["takes"]))
    print("familiar range {:g}-{:g} deg; wrote {}.safetensors".format(*measured["degrees"], out))


def _add_style(args: argparse.Namespace) -> None:
    from styleerd.train.add_style import AddStyleConfig, add_style

    out = Path(args.output)
    out = out.with_suffix("") if out.suffix in (".safetensors", ".json") else out
    check_output(out.with_suffix(".safetensors"), *args.clips)
    config = AddStyleConfig(steps=args.steps, max_minutes=args.minutes)
    explicit = _read_joint_map(args.joint_map) if args.joint_map else None
    added = add_style(args.model, args.name, args.clips, out, args.content, args.like, config, args.data, explicit)
    print(
        f"added {added['name']} from {len(added['clips'])} clips ({added['frames']} frames, starting like "
        f"{added['started_like']}): "
        f"{added['steps']} steps, {added['minutes']:.1f} min; wrote {out}.safetensors"
    )


def _styles(args: argparse.Namespace) -> None:
    from styleerd.models import DEFAULT_MODEL, MODELS_DIR

    if args.model:
        return _model_styles(args.model)
    shipped = sorted(
        (
            p.with_suffix("")
            for p in MODELS_DIR.glob("*.json")
            if json.loads(p.read_text()).get("kind") == "styleerd-generator"
        ),
        key=lambda p: (p.name != DEFAULT_MODEL, p.name),
    )
    for i, stem in enumerate(shipped):  # the default model first
        if i:
            print()
        _model_styles(str(stem))


def _model_styles(name: str | None) -> None:
    from styleerd.model.stored import load_generator_weights, model_stem
    from styleerd.models import LICENCE

    model = load_generator_weights(name)
    meta = model.meta
    print(f"model:    {model_stem(name).with_suffix('.safetensors')}")
    c = model.config
    print(f"styles:   {', '.join(c.styles)} (neutral: {c.neutral_style})")
    for added in meta.get("added_styles", []):
        print(
            f"added:    {added['name']} (a target only), from {len(added['clips'])} clips ({added['frames']} frames) "
            f"in {added['minutes']:.1f} min"
        )
    print(f"contents: {', '.join(model.config.contents)}")
    print(
        f"skeleton: {model.skeleton.n_joints} joints, trained at {meta['data']['fps']:g} fps on "
        f"{meta['data']['dataset']}"
    )
    lo, hi = model.familiar
    print(
        f"familiar: the network's pose while its identity pass is within {lo:g} deg of the input, the input's "
        f"from {hi:g} deg ({'measured by styleerd familiar' if 'familiar' in meta else 'not measured: the default'})"
    )
    print(f"licence:  {meta.get('licence', LICENCE)}")


def _evaluate(args: argparse.Namespace) -> None:
    from styleerd.train.trainer import evaluate

    if args.json:
        check_output(args.json)
    report = evaluate(
        Path(args.model) if args.model else None,
        args.data,
        args.split,
        recognisers=Path(args.recognisers) if args.recognisers else None,
    )
    print(json.dumps(report, indent=1))
    if args.json:
        from styleerd.atomic import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")


def _eval_runtime(args: argparse.Namespace) -> None:
    from styleerd.eval.metrics import runtime_report
    from styleerd.model.checkpoint import load_generator, load_labeller

    model, _ = load_generator(args.model)
    print(json.dumps(runtime_report(model, load_labeller()[0], args.data), indent=1))


def _eval_quality(args: argparse.Namespace) -> None:
    from styleerd.eval.metrics import evaluate_model
    from styleerd.model.checkpoint import load_generator

    result = evaluate_model(load_generator(args.model)[0], args.data, args.split, args.pose)
    print(json.dumps(result, indent=1))
    if args.json:  # one entry per model, the file's others kept (docs/recipes-val.json: a choice made on val)
        from styleerd.atomic import atomic_write_text

        path = Path(args.json)
        kept = json.loads(path.read_text()) if path.is_file() else {}
        kept[args.as_name or (Path(args.model).name if args.model else "shipped")] = result
        atomic_write_text(path, json.dumps(kept, indent=1) + "\n")


def _eval_streamed(args: argparse.Namespace) -> None:
    from styleerd.eval.metrics import played_content_of_ceiling, root_speeds, runtime_transfers
    from styleerd.eval.recipes import neutralisation
    from styleerd.model import checkpoint as ckpt

    if args.json:
        check_output(args.json)
    model, _ = ckpt.load_generator(args.model)
    style_rec, content_rec, _ = ckpt.load_recognisers()
    report = runtime_transfers(
        model, ckpt.load_labeller()[0], style_rec, content_rec, args.data, root_speed=args.root_speed, pose=args.pose
    )
    report["summary"] = neutralisation(report, model.config.neutral_style)
    report["summary"]["cra_of_ceiling"] = played_content_of_ceiling(report, model.config.neutral_style)
    report["root_speed_by_content_and_style"] = root_speeds(
        data_dir=args.data
    )  # the pace of each style in the training clips
    print(json.dumps(report, indent=1))
    if args.json:
        from styleerd.atomic import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")


def _eval_recipes(args: argparse.Namespace) -> None:
    from styleerd.atomic import atomic_write_text
    from styleerd.eval.recipes import markdown, recipe_models, recipe_table, tradeoff_plot

    out = check_output(args.out)
    rows = recipe_table(args.data, args.only or None)
    kept = out.with_suffix(".json")
    if args.only and kept.is_file():  # the other rows as they were measured, in the models' order
        before = json.loads(kept.read_text())
        rows = {k: rows.get(k) or before[k] for k in recipe_models() if k in rows or k in before}
    atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), markdown(rows))
    tradeoff_plot(rows, out.with_suffix(".png"))
    print(markdown(rows))


def _eval_rotations(args: argparse.Namespace) -> None:
    from styleerd.eval.rotations import markdown, rotation_report, write
    from styleerd.model.checkpoint import load_generator

    model, meta = load_generator(args.model)
    report = rotation_report(model, meta["data"]["fps"], args.data, stylised=args.style)
    if args.out:
        write(report, Path(args.out))
    print(markdown(report))


def _eval_actions(args: argparse.Namespace) -> None:
    from styleerd.atomic import atomic_write_text
    from styleerd.eval.actions import (
        action_filmstrips,
        evaluate_actions,
        evaluate_feet,
        markdown,
        performer_changes,
        style_recogniser,
    )
    from styleerd.model.stored import load_generator_weights

    out = check_output(args.out)
    model = load_generator_weights(args.model)
    report = evaluate_actions(model, args.data, progress=print)
    report["performers"] = performer_changes(model, args.data)
    if not args.no_feet:
        report["feet"] = evaluate_feet(model, args.data, recogniser=style_recogniser(model))
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), markdown(report) + "\n")
    print(markdown(report))
    for path in action_filmstrips(model, out, args.data):
        print(f"wrote {path}")


def _eval_corpus(args: argparse.Namespace) -> None:
    from styleerd.atomic import atomic_write_text
    from styleerd.eval.corpus import evaluate_corpus, markdown
    from styleerd.model.stored import load_generator_weights

    out = check_output(args.out)
    report = evaluate_corpus(load_generator_weights(args.model), args.data, progress=print)
    text = markdown(report)
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), text)
    print(text)


def _eval_clip_styles(args: argparse.Namespace) -> None:
    from styleerd.eval.clip_recogniser import evaluate_clip_styles, markdown, write
    from styleerd.model.stored import load_generator_weights

    out = check_output(args.out)
    report = evaluate_clip_styles(load_generator_weights(args.model), args.data, args.retrain)
    write(report, out)
    print(markdown(report))


def _eval_labels(args: argparse.Namespace) -> None:
    from styleerd.eval.labels import evaluate_labels, markdown, write
    from styleerd.model.stored import load_generator_weights, load_labeller_weights

    out = check_output(args.out)
    labeller = load_labeller_weights(Path(args.labeller)) if args.labeller else None
    report = evaluate_labels(load_generator_weights(args.model), args.data, labeller)
    write(report, out)
    print(markdown(report))


def _eval_ablations(args: argparse.Namespace) -> None:
    from styleerd.atomic import atomic_write_text
    from styleerd.eval.ablations import ABLATIONS, RUNS_DIR, ablation_table, markdown, shipped_budget, train_ablations

    if not args.no_train:
        train_ablations(Path(args.runs) if args.runs else RUNS_DIR, args.data, args.threads, args.device)
    rows = ablation_table(args.data, args.only or None)
    out = Path(args.out)
    kept = out.with_suffix(".json")
    if args.only and kept.is_file():  # the other rows as they were measured, in the table's order
        before = json.loads(kept.read_text())
        rows = {k: rows.get(k) or before[k] for k in ABLATIONS if k in rows or k in before}
    epochs = shipped_budget()[1]
    atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), markdown(rows, epochs))
    print(markdown(rows, epochs))


def _bench(args: argparse.Namespace) -> None:
    from styleerd.atomic import atomic_write_text
    from styleerd.eval.bench import STREAMS, plot, run_bench, table
    from styleerd.model.checkpoint import load_generator

    report = run_bench(load_generator(args.model)[0], args.steps, tuple(args.streams or STREAMS))
    print(table(report))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.json}")
    if args.plot:
        plot(report, args.plot)
        print(f"wrote {args.plot}")


def _report(args: argparse.Namespace) -> None:
    from styleerd.eval.report import write_report

    print(f"wrote {write_report(Path(args.docs), args.data, args.steps, keep=tuple(args.keep))}")


def _filmstrip(args: argparse.Namespace) -> None:
    from styleerd.data.datasets import data_root, find_clips
    from styleerd.data.windows import split_takes
    from styleerd.eval.plots import style_filmstrip
    from styleerd.model.stored import load_generator_weights

    model = load_generator_weights(args.model)
    clips = find_clips(data_root(args.data), "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    if args.clip:
        chosen = [c for c in clips if c.name == args.clip]
    else:
        chosen = [
            c
            for c in clips
            if split[c.name] == "test" and c.style == model.config.neutral_style and c.content == args.content
        ]
    if not chosen:
        raise StyleERDError(f"no clip {args.clip or f'(neutral {args.content} test clip)'} in bandai-namco-2")
    styles = args.styles.split(",") if args.styles else None
    unknown = set(styles or ()) - set(model.config.styles)
    if unknown:
        raise StyleERDError(f"--styles: the model has no style {', '.join(sorted(unknown))}")
    style_filmstrip(model, chosen[0], args.output, cards=args.cards, styles=styles)
    print(f"wrote {args.output} ({chosen[0].name})")


def _serve(args: argparse.Namespace) -> None:
    from styleerd.serve.server import ServeConfig, serve_forever

    config = ServeConfig(
        host=args.host,
        port=args.port,
        max_streams=args.max_streams,
        max_watchers=args.max_watchers,
        max_message=args.max_message,
        queue=args.queue,
        backend=args.backend,
        threads=args.threads,
        server_id=args.id or "",
        loop=args.loop,
        data=args.data,
        max_joints=args.max_joints,
        origins=tuple(args.allow_origin),
        hosts=tuple(args.allow_host),
        model=args.model,
    )
    if args.warm_only:
        from styleerd.serve.server import StyleServer

        StyleServer(config).warm_up()
        print(f"styleerd serve: the {args.backend} engine is compiled and cached")
        return
    serve_forever(config, args.workers)


def _stream_bvh(args: argparse.Namespace) -> None:
    from styleerd.serve.client import stream_bvh

    mix = _style_or_mix(args)
    if args.output:
        check_output(args.output, args.input)
    print(
        stream_bvh(
            args.input,
            args.to,
            args.style,
            args.intensity,
            mix,
            args.output,
            args.input_style,
            args.content,
            not args.fast,
            args.root_speed,
            args.reconnect,
        )
    )


def _load_test(args: argparse.Namespace) -> None:
    from styleerd.serve.loadtest import run_load_test

    server = ("--workers", str(args.workers), "--backend", args.backend, "--threads", str(args.threads))
    server += ("--loop", args.loop)
    summary, _ = run_load_test(
        args.clients,
        args.seconds,
        args.output,
        args.faulty,
        args.streams_per_client,
        args.labels,
        server,
        pose=args.pose,
    )
    print(summary)


def _vmc(args: argparse.Namespace) -> None:
    from styleerd.serve.vmc import run_bridge

    run_bridge(
        args.listen,
        args.send,
        args.style,
        args.intensity,
        _style_or_mix(args),
        args.host,
        args.fps,
        args.parts,
        args.model,
        args.root_speed,
    )


def _demo(args: argparse.Namespace) -> None:
    from styleerd.eval.demo import run_demo

    print(run_demo(Path(args.out), args.data))


def _server_id(text: str) -> str:
    """An argument type: a server's name, as a token's prefix and a metrics label take it."""
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,40}", text):
        raise argparse.ArgumentTypeError(f"{text[:60]!r}: a server's name is 1 to 40 letters, digits, '-' or '_'")
    return text


def _whole(low: int):
    """An argument type: a whole number of at least ``low``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"{value} is too small: at least {low}")
        return value

    return parse


def _port(text: str) -> int:
    value = _whole(0)(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{value}: a port number is 0..65535")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive number")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse, with a mistake reported on one line (the usage is one ``-h`` away)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} -h')\n")


POSES = ("input", "network")  # runtime.stylizer.POSES, here without importing numba
POSE_HELP = (
    "what the output's poses are built on: input (default), the input's own pose plus the style's posture, "
    "which keeps any action; network, the network's pose (the paper's output)"
)
SERVE_BACKENDS = ["numpy", "numba", "onnx"]  # serve's and load-test's --backend
EVENT_LOOPS = ["auto", "uvloop", "asyncio"]  # serve's and load-test's --loop
MODEL_HELP = "a model file, or a model name in $STYLEERD_MODELS or among the shipped ones (default: styleerd-bandai2)"
GROUPS = {
    "use": ("transfer", "styles", "info", "resample", "export-onnx", "demo"),
    "live": ("serve", "stream-bvh", "vmc", "load-test"),
    "train (styleerd[train])": (
        "data",
        "train",
        "add-style",
        "soup",
        "posture",
        "familiar",
        "train-labeller",
        "train-recognisers",
        "train-fmd",
    ),
    "evaluate (styleerd[train])": ("evaluate", "eval", "eval-runtime", "bench", "report", "filmstrip"),
}


def _grouped(helps: dict[str, str]) -> str:
    lines = []
    for group, names in GROUPS.items():
        lines.append(f"{group}:")
        lines += [f"  {name:<18} {helps[name]}" for name in names]
    return "\n".join(lines) + "\n\n'styleerd COMMAND -h' for a command's options."


def _target_arguments(p: argparse.ArgumentParser) -> None:
    """--style, --intensity and --mix: the target, as transfer, stream-bvh and vmc take it."""
    from styleerd.models import shipped_styles

    p.add_argument(
        "--style",
        help=f"target style; the shipped model's: {', '.join(shipped_styles())} ('styleerd styles --model M' for "
        "another)",
    )
    p.add_argument("--intensity", type=float, default=1.0, help="0 = neutral, 1 = full style, up to 2")
    p.add_argument("--mix", help="a mixture instead of --style, e.g. elderly=0.5,feminine=0.5 (scaled by --intensity)")


def _label_arguments(p: argparse.ArgumentParser) -> None:
    """--input-style and --content: the input's labels, inferred online where not given."""
    p.add_argument("--input-style", help="the input's style (default: inferred online from the frames)")
    p.add_argument("--content", help="the input's content, e.g. walk (default: inferred online)")


def _transfer_command(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """``styleerd transfer``: one file, or many in a process pool."""

    p = command(
        "transfer", "stylise BVH, glTF/VRM or FBX motion on any humanoid skeleton; several files or folders at once"
    )
    p.add_argument(
        "input",
        nargs="+",
        help="IN.bvh, IN.glb / .gltf / .vrm (its first skin and animation; written back as the same file) or IN.fbx "
        "(through Blender: styleerd[blender]); several files or folders with -o DIR",
    )
    _target_arguments(p)
    p.add_argument(
        "--parts",
        help="body parts with targets of their own, the others following --style/--mix: PART=STYLE[:INTENSITY] or "
        "PART=input (its own motion), "
        "parts legs, torso, head, arms; e.g. legs=elderly,torso=exhausted:0.5,arms=input",
    )
    _label_arguments(p)
    p.add_argument(
        "--backend",
        default="numpy",
        choices=["torch", "numpy", "numba", "onnx", "onnx-plain"],
        help="network step backend (default numpy; torch is the reference; numba is the fastest)",
    )
    p.add_argument(
        "--no-cleanup",
        action="store_true",
        help="leave the feet as the network outputs them (default: pin planted feet)",
    )
    p.add_argument(
        "--root-speed",
        action="store_true",
        help="the root's ground speed in the target style too (from the network; default: the input's root path as it "
        "is)",
    )
    p.add_argument("--pose", choices=POSES, default="input", help=POSE_HELP)
    p.add_argument(
        "--animation",
        default="all",
        metavar="NAME|all",
        help="glTF/GLB/VRM/FBX input: the animation (FBX: take) to stylise, by name (default: all, each keeping "
        "its name)",
    )
    p.add_argument(
        "--onto",
        metavar="AVATAR",
        help="put the stylised motion on this character (.vrm, .glb, .gltf, .fbx with styleerd[blender]; animated "
        "or not), written into a copy of it (-o OUT.vrm / .glb / .fbx) or as a BVH of its skeleton",
    )
    p.add_argument(
        "--keep-original",
        action="store_true",
        help="glTF/GLB/VRM output: keep the input's animations and add the stylised ones as NAME-STYLE",
    )
    p.add_argument(
        "--joint-map", help="JSON object {model joint: input joint} completing or overriding the automatic mapping"
    )
    p.add_argument(
        "--write-joint-map",
        metavar="MAP.json",
        help='write the joint map the automatic mapping finds for the input (best guesses, "" where none) to edit '
        "and pass back with --joint-map, and stop",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "-o",
        "--output",
        help="OUT.bvh (the input's skeleton and channel layout), OUT.glb, OUT.fbx, or from a glTF input OUT.glb/.vrm "
        "(the input file, animation replaced); a folder for several inputs",
    )
    p.add_argument("--jobs", type=_whole(1), help="with several inputs: worker processes (default: one per core)")
    p.add_argument(
        "--timeout",
        type=float,
        default=600.0,
        help="with several inputs: seconds a file may take before it is skipped (default 600)",
    )
    p.add_argument(
        "--max-memory",
        type=float,
        help="with several inputs: GiB a worker may use before its file is skipped (default: no limit)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="with several inputs: skip the outputs already written (writes are atomic: they are complete)",
    )
    p.add_argument(
        "--to", choices=["bvh", "glb", "fbx"], help="with several inputs: the outputs' kind (default: each input's own)"
    )
    p.add_argument(
        "--mesh",
        action="store_true",
        help=".glb: add a simple skinned body (a prism per bone, its front marked) so the file shows in any viewer",
    )
    p.set_defaults(func=_transfer)


def _use_commands(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Commands that stylise and inspect motion: transfer, styles, info, resample, export-onnx, demo."""
    _transfer_command(command)

    p = command("styles", "styles and contents of each shipped model (or of --model)")
    p.add_argument("--model", help=MODEL_HELP)
    p.set_defaults(func=_styles)

    p = command(
        "info",
        "describe a motion or character file (BVH, glTF/VRM/VRMA, FBX): animations, skeleton, its joint mapping "
        "onto the model; or (--system) this machine as the engine sees it",
    )
    p.add_argument(
        "file", nargs="?", help="a BVH, glTF, GLB, VRM, VRMA or FBX file; a folder: each of its files in two lines"
    )
    p.add_argument(
        "--system",
        action="store_true",
        help="the CPU, the BLAS libraries and threading layers loaded, numba's threads, the engine's settings (the "
        "numba step's are measured on this machine at first use, a few seconds, and cached)",
    )
    p.add_argument(
        "--recalibrate",
        action="store_true",
        help="with --system: measure the numba step's settings again (after a change of hardware, or a first use "
        "on a busy machine)",
    )
    p.add_argument("--model", help=f"the model mapped onto (with --system: whose step is measured); {MODEL_HELP}")
    p.add_argument("--joint-map", help="JSON object {model joint: input joint} completing the automatic mapping")
    p.set_defaults(func=_info)

    p = command("resample", "change a BVH file's frame rate")
    p.add_argument("input", help="the BVH file")
    p.add_argument("--fps", type=float, required=True, help="the new frame rate, 1 to 1000")
    p.add_argument("-o", "--output", required=True, help="the BVH written (the same skeleton and channel layout)")
    p.set_defaults(func=_resample)

    p = command(
        "export-onnx", "the network step as an ONNX graph (LSTM ops, opset 15) with explicit state, for engines"
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "-o",
        "--output",
        default="stylizer.onnx",
        help="the graph (default stylizer.onnx), its sidecar beside it (.json)",
    )
    p.add_argument(
        "--styles",
        help="only these styles' branches, e.g. elderly,feminine: a smaller, faster graph (default: every style)",
    )
    p.add_argument(
        "--plain",
        action="store_true",
        help="the LSTM cells written out as MatMul/Sigmoid/Tanh (for runtimes without the LSTM op)",
    )
    p.set_defaults(func=_export_onnx)

    p = command("demo", "the main job on a bundled input: every style, BVH files + an HTML page to watch them")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--data", help="data folder (optional: adds a real test clip)")
    p.set_defaults(func=_demo)


def _live_commands(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Commands for live streams: serve, stream-bvh, vmc, load-test."""
    p = command("serve", "the real-time style server (WebSocket, docs/PROTOCOL.md) and its browser viewer")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback only)")
    p.add_argument("--port", type=_port, default=8765, help="the WebSocket and viewer port (default 8765)")
    p.add_argument(
        "--workers", type=_whole(1), default=1, help="processes sharing the port (SO_REUSEPORT), e.g. one per core"
    )
    p.add_argument("--max-streams", type=_whole(1), default=256, help="open streams per worker")
    p.add_argument("--max-watchers", type=_whole(1), default=64, help="live viewers at once per worker")
    p.add_argument(
        "--loop",
        choices=EVENT_LOOPS,
        default="auto",
        help="the event loop: uvloop where installed (auto), or asyncio's own",
    )
    p.add_argument(
        "--id",
        type=_server_id,
        help="this process's name behind a load balancer (deploy/): private tokens start with it, /metrics label it",
    )
    p.add_argument(
        "--max-message", type=_whole(1024), default=1 << 20, help="largest message in bytes (larger: closed with 1009)"
    )
    p.add_argument("--queue", type=_whole(1), default=64, help="per stream: frames waiting, and stylised frames unsent")
    p.add_argument(
        "--backend",
        default="numba",
        choices=SERVE_BACKENDS,
        help="the network step (default numba: compiled on the first start after an install, then cached)",
    )
    p.add_argument(
        "--threads",
        type=_whole(1),
        default=1,
        help="threads of each batched step (numba kernels, or shards of the streams): for hundreds of streams a worker",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--data", help="data folder for the viewer's real demo clips (optional)")
    p.add_argument("--max-joints", type=_whole(1), default=512, help="joints of a stream's skeleton (default 512)")
    p.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="ORIGIN",
        help="a web page origin (e.g. https://app.example) that may open streams besides the server's own; '*': any",
    )
    p.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a host name the server answers to (default: its address, and localhost names on loopback)",
    )
    p.add_argument(
        "--warm-only",
        action="store_true",
        help="compile and calibrate the engine into the cache, then exit (a container image's build step)",
    )
    p.set_defaults(func=_serve)

    p = command("stream-bvh", "play a BVH to a style server in real time, as a mocap source")
    p.add_argument("input", help="the BVH file played")
    p.add_argument("--to", default="ws://127.0.0.1:8765/", help="server URL")
    _target_arguments(p)
    _label_arguments(p)
    p.add_argument("--fast", action="store_true", help="send as fast as replies come, not in real time")
    p.add_argument(
        "--root-speed",
        action="store_true",
        help="the root's ground speed in the target style too (the hello's root_speed)",
    )
    p.add_argument(
        "--reconnect",
        action="store_true",
        help="when the connection is lost or the server goes away, connect again (with backoff: through a balancer, "
        "to another server) and go on from the first unanswered frame",
    )
    p.add_argument("-o", "--output", help="write the stylised stream as BVH")
    p.set_defaults(func=_stream_bvh)

    p = command("vmc", "VMC protocol bridge: receive bones over OSC/UDP, stylise, send them on")
    p.add_argument("--listen", type=_port, default=39539, help="UDP port to receive VMC on")
    p.add_argument("--send", type=_port, default=39540, help="UDP port to send the stylised VMC to")
    p.add_argument("--host", default="127.0.0.1", help="host to send to (and to listen on)")
    _target_arguments(p)
    p.add_argument("--fps", type=_positive, default=30.0, help="the sender's frame rate (velocities are per second)")
    p.add_argument(
        "--parts",
        help="body parts with targets of their own, as for transfer: e.g. arms=input (tracked hands keep their own "
        "motion)",
    )
    p.add_argument(
        "--root-speed",
        action="store_true",
        help="the hips move at the style's pace, as transfer --root-speed (their path drifts from the performer's)",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.set_defaults(func=_vmc)

    p = command(
        "load-test",
        "N real-time stream-bvh clients against a fresh server: latency, drops, CPU (with --faulty: a soak test)",
    )
    p.add_argument("--clients", type=_whole(1), default=200, help="connections")
    p.add_argument(
        "--streams-per-client",
        type=_whole(1),
        default=1,
        help="streams on each connection, one message a frame for them all (a game's crowd)",
    )
    p.add_argument("--seconds", type=_positive, default=60.0, help="how long the clients stream (default 60)")
    p.add_argument("--workers", type=_whole(1), default=1, help="server workers")
    p.add_argument("--backend", choices=SERVE_BACKENDS, default="numba", help="the server's backend")
    p.add_argument("--threads", type=_whole(1), default=1, help="the server's threads per batched step")
    p.add_argument("--loop", choices=EVENT_LOOPS, default="auto", help="the server's event loop")
    p.add_argument(
        "--labels",
        action="store_true",
        help="the hellos give the clip's input style and content (a neutral walk): no labeller runs on the server",
    )
    p.add_argument("--pose", choices=POSES, default="input", help="the pose path the clients ask for: " + POSE_HELP)
    p.add_argument(
        "--faulty",
        type=_whole(0),
        default=0,
        help="soak test: this many more clients misbehave in turn (malformed frames, slow readers, vanishing, bad "
        "hellos)",
    )
    p.add_argument("-o", "--output", help="write the figures as JSON")
    p.set_defaults(func=_load_test)


def _train_commands(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Commands that prepare data and train models."""
    data = command("data", "datasets").add_subparsers(dest="data_command", required=True)
    p = data.add_parser("prepare", help="unpack, parse and cache features; print clips and frames per style x content")
    p.add_argument("--data", help="data folder (default: $STYLEERD_DATA, else ../shared/data)")
    p.add_argument("--cache", help="cache folder (default: $STYLEERD_CACHE, else ~/.cache/styleerd)")
    p.add_argument("--datasets", nargs="+", metavar="NAME", help="subset of: bandai-namco-2 bandai-namco-1 xia-sample")
    p.add_argument("--fps", type=_positive, default=30.0, help="frame rate of the features (default 30)")
    p.add_argument("--workers", type=_whole(1), help="processes (default: one per core)")
    p.set_defaults(func=_data_prepare)

    p = command("train", "train a Style-ERD model (resumable: rerun the same command)")
    p.add_argument("--config", required=True, help="YAML file of TrainConfig fields (see configs/)")
    p.add_argument("--out", help="run folder (default runs/<name>)")
    p.add_argument("--data", help="data folder")
    p.add_argument("--export", help="also write the best generator to this model path (no suffix)")
    p.add_argument(
        "--device", help="train on this torch device (e.g. cuda) instead of the config's; a run may resume on another"
    )
    p.set_defaults(func=_train)

    p = command(
        "add-style",
        "a new style from 1 to 20 clips of it, on any skeleton: trains one more branch, every old style unchanged",
    )
    p.add_argument("name", help="the new style's name (lower case, e.g. sneaky)")
    p.add_argument(
        "clips",
        nargs="+",
        help="BVH or glTF/VRM clips of the style (any humanoid skeleton and frame rate, retargeted as transfer does)",
    )
    p.add_argument(
        "-o", "--output", required=True, help="the new model file (e.g. models/mine): the old model plus the new style"
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "--content",
        nargs="+",
        help="the clips' content, e.g. walk (one for all, or one per clip; default: inferred online)",
    )
    p.add_argument(
        "--like", help="start the new branch from this style's (default: the style the labeller finds closest)"
    )
    p.add_argument("--steps", type=_whole(1), default=1200, help="training steps (default 1200)")
    p.add_argument(
        "--minutes", type=_positive, default=8.0, help="stop after this many minutes of training (default 8)"
    )
    p.add_argument("--joint-map", help="JSON object {model joint: clip joint} completing the automatic mapping")
    p.add_argument("--data", help="data folder (the neutral clips of the model's dataset are the content to stylise)")
    p.set_defaults(func=_add_style)

    p = command("soup", "one model from several fine-tuned from the same start: the weighted average of their weights")
    p.add_argument("models", nargs="+", help="saved generators (stems or shipped names), fine-tuned from one start")
    p.add_argument("-o", "--output", required=True, help="the averaged model (no suffix)")
    p.add_argument("--weights", nargs="+", type=float, help="one per model, summing to 1 (default: equal)")
    p.set_defaults(func=_soup)

    p = _measured_into_model(
        command,
        "posture",
        "measure each style's posture (its change to the pose, averaged over the training split's neutral walks) and "
        "store it in the model: what an action the network never learnt is turned by",
        _posture,
    )
    p.add_argument(
        "--frame",
        choices=["heading", "body"],
        default="body",
        help="the frame the joint offsets are kept and reached in: the body's heading (up the world's) or its own",
    )
    _measured_into_model(
        command,
        "familiar",
        "measure how far the identity pass may be from the input (mean joint angle) before the input's own pose "
        "takes over (pose input), on actions no training run sees, and store it in the model",
        _familiar,
    )

    for name, (text, default, _) in HELPER_MODELS.items():
        p = command(name, text)
        p.add_argument("--config", help="YAML TrainConfig (dataset, seed, threads, window, classifier_* fields)")
        p.add_argument("--out", help=f"model path without suffix (default models/{default})")
        p.add_argument("--data", help="data folder")
        p.set_defaults(func=_train_helper)


def _evaluate_commands(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Commands that measure models and the runtime."""
    p = command("evaluate", "SRA, CRA and reconstruction error of a model on real test windows")
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "--split", default="test", choices=["train", "val", "test"], help="the windows' split (default test)"
    )
    p.add_argument("--recognisers", help="recognisers path without suffix (default: the shipped ones)")
    p.add_argument("--data", help="data folder")
    p.add_argument("--json", help="also write the figures to this JSON file")
    p.set_defaults(func=_evaluate)

    p = command(
        "eval-runtime", "label inference accuracy, foot skate before/after cleanup, pop at a style switch (test split)"
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_runtime)

    p = command("bench", "runtime table: latency per backend, whole clips, throughput curve, FLOPs, memory")
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--steps", type=_whole(1), default=2000, help="frames timed per latency figure")
    p.add_argument(
        "--streams", type=_whole(1), nargs="+", help="concurrent streams of the throughput curve (default 1 .. 4096)"
    )
    p.add_argument("--json", help="also write the figures to this JSON file")
    p.add_argument("--plot", help="also draw the throughput curve into this picture (.png)")
    p.set_defaults(func=_bench)

    p = command("report", "regenerate docs/RESULTS.md: quality, ablations, runtime, online figures, pictures")
    p.add_argument("--docs", default="docs", help="the folder of RESULTS.md, its JSON and pictures (default docs)")
    p.add_argument("--steps", type=_whole(1), default=2000, help="frames timed per latency figure")
    p.add_argument(
        "--keep",
        nargs="*",
        default=[],
        choices=["ablations", "bench"],
        help="read these parts from their JSON in --docs, not measured again (their models and code unchanged since)",
    )
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_report)

    p = command("filmstrip", "picture: a neutral test clip and its transfer into every style")
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--clip", help="Bandai-Namco-2 clip name (default: the first neutral test clip of --content)")
    p.add_argument("--content", default="walk", help="the content of the clip picked (default walk)")
    p.add_argument("--data", help="data folder")
    p.add_argument("-o", "--output", default="docs/filmstrip-bandai2.png", help="a picture, or an animated GIF (.gif)")
    p.add_argument("--styles", help="only these target styles, e.g. elderly,feminine (default: every other style)")
    p.add_argument("--cards", help="also one small picture per style in this folder (e.g. docs/styles)")
    p.set_defaults(func=_filmstrip)

    ev = command("eval", "quality figures: FMD, SRA, CRA, responsiveness, ablations").add_subparsers(
        dest="eval_command", required=True
    )
    _eval_subcommands(ev)


def _eval_subcommands(sub: argparse._SubParsersAction) -> None:
    """``styleerd eval quality | streamed | recipes | rotations | actions | ablations``."""
    p = sub.add_parser(
        "quality", help="FMD (and its floor), SRA, CRA, responsiveness, jitter, reconstruction of one model"
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "--split",
        choices=("test", "val"),
        default="test",
        help="val: to choose between models without looking at the test set",
    )
    p.add_argument("--data", help="data folder")
    p.add_argument(
        "--json", help="also write the figures into this JSON file, under the model's name (other entries kept)"
    )
    p.add_argument("--as-name", help="the entry's name in --json (default: the model's file name, or shipped)")
    p.add_argument(
        "--pose",
        choices=POSES,
        default="network",
        help="the transfers' poses: " + POSE_HELP + " (default network: the network judged)",
    )
    p.set_defaults(func=_eval_quality)
    p = sub.add_parser(
        "streamed",
        help="whole test clips streamed as `transfer` runs them: styled -> neutral, neutral -> each style, labels "
        "given and inferred, judged as played",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument(
        "--root-speed", action="store_true", help="stream with the root's speed stylised (transfer --root-speed)"
    )
    p.add_argument("--pose", choices=POSES, default="input", help=POSE_HELP)
    p.add_argument("--json", help="also write the figures to this JSON file")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_streamed)
    p = sub.add_parser(
        "recipes",
        help="every kept model (shipped, models/recipes, ablations) side by side: FMD vs CRA per style, back to "
        "neutral; JSON, table, trade-off plot",
    )
    p.add_argument("--out", default="docs/recipes.md", help="Markdown table (a .json and the .png plot beside it)")
    p.add_argument(
        "--only",
        nargs="*",
        help="evaluate only these names (as listed in the table); the other rows are kept from the existing JSON",
    )
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_recipes)
    p = sub.add_parser(
        "rotations",
        help="joint rotations on other skeletons, swing and twist: round trip at intensity 0, and the change a style "
        "makes",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--style", default="elderly", help="the style whose change is measured (default elderly)")
    p.add_argument("--out", default="docs/rotations.md", help="Markdown table (a .json beside it); empty: print only")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_rotations)
    p = sub.add_parser(
        "actions",
        help="held-out actions of other performers and skeletons (kicks, dances, swims ...): the action kept, the "
        "style's change (against the walks' and a real performer's), the feet",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--out", default="docs/actions.md", help="Markdown tables (a .json beside it)")
    p.add_argument("--no-feet", action="store_true", help="only the action table")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_actions)
    p = sub.add_parser(
        "corpus",
        help="every take of cmu-sample, Bandai-Namco-1 and xia-sample, whole, identity and into each style: the "
        "worst take of each figure (action kept, feet)",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--out", default="docs/corpus.md", help="Markdown tables (a .json beside it)")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_corpus)
    p = sub.add_parser(
        "clip-styles",
        help="a second judge of another design (a GRU on whole clips' joint positions and root velocity): test takes "
        "streamed back to neutral and into each style, read as their target or still as their source",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--out", default="docs/clip-styles.md", help="Markdown table (a .json beside it)")
    p.add_argument("--retrain", action="store_true", help="train the recogniser again (models/clip-recogniser-bandai2)")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_clip_styles)
    p = sub.add_parser(
        "labels",
        help="what the online labeller reads on other performers' clips (xia-sample, cmu-sample, Bandai-Namco-1): "
        "confident wrong styles",
    )
    p.add_argument("--model", help=MODEL_HELP)
    p.add_argument("--labeller", help="another labeller (a path without suffix; default: the model's)")
    p.add_argument("--out", default="docs/labels.md", help="Markdown tables (a .json beside it)")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_labels)
    p = sub.add_parser(
        "ablations",
        help="train what is missing at the shipped run's budget (resumable) and tabulate the paper's ablations",
    )
    p.add_argument("--threads", type=_whole(1), default=1, help="torch threads of the training runs (default 1)")
    p.add_argument(
        "--runs", help="run folders (checkpoints; default models/ablations/training, kept in git between sessions)"
    )
    p.add_argument(
        "--device", default="cpu", help="train on this torch device (e.g. cuda); a run may resume on another"
    )
    p.add_argument("--no-train", action="store_true", help="only evaluate the models in models/ablations/")
    p.add_argument(
        "--only",
        nargs="*",
        help="evaluate only these rows (e.g. 'rec only' full); the others are kept from the existing JSON",
    )
    p.add_argument("--out", default="docs/ablations.md", help="Markdown table (a .json beside it)")
    p.add_argument("--data", help="data folder")
    p.set_defaults(func=_eval_ablations)


def build_parser() -> argparse.ArgumentParser:
    from styleerd.models import LICENCE

    parser = _Parser(
        prog="styleerd",
        description="Online motion style transfer (Style-ERD), frame by frame, on a CPU.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help="one of the commands below")
    helps: dict[str, str] = {}

    def command(name: str, text: str) -> argparse.ArgumentParser:
        helps[name] = text
        return sub.add_parser(name, description=text)

    for group in (_use_commands, _live_commands, _train_commands, _evaluate_commands):
        group(command)
    parser.epilog = _grouped(helps) + f"\nShipped models: {LICENCE}."
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except StyleERDError as e:
        print(f"styleerd: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("styleerd: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `styleerd info F | head -1`: the reader left; stop quietly, as a Unix tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes stdout
        return 141
    return 0


if __name__ == "__main__":
    sys.exit(main())
