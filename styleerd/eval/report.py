"""``styleerd report``: regenerate docs/RESULTS.md, every table and picture, from the shipped
models, with the same functions the individual commands run (``eval quality``,
``eval ablations --no-train``, ``bench``, ``eval-runtime``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.data.datasets import Clip, data_root, find_clips, load_motion
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError
from styleerd.eval.ablations import ablation_table, markdown, model_stem, shipped_budget
from styleerd.eval.bench import STREAMS, plot, run_bench, table
from styleerd.eval.metrics import evaluate_model, runtime_report
from styleerd.eval.plots import filmstrip, style_filmstrip
from styleerd.eval.rotations import markdown as markdown_rotations
from styleerd.eval.rotations import rotation_report
from styleerd.eval.rotations import write as write_rotations
from styleerd.model.checkpoint import load_generator, load_labeller
from styleerd.motion.resample import resample
from styleerd.runtime.offline import stylise_motion


def neutral_test_walk(data_dir: str | None, neutral: str) -> Clip:
    """The first neutral Bandai-Namco-2 walk of the test split (the clip the pictures show)."""
    clips = find_clips(data_root(data_dir), "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    return next(c for c in clips if split[c.name] == "test" and c.style == neutral and c.content == "walk")


def pictures(docs: Path, data_dir: str | None) -> dict[str, str]:
    model, _ = load_generator()
    c = model.config
    clip = neutral_test_walk(data_dir, c.neutral_style)
    motion = resample(load_motion(clip), 30.0)
    out = {}
    style_filmstrip(model, clip, docs / "filmstrip-bandai2.png", cards=docs / "styles")
    out["every style"] = "filmstrip-bandai2.png"
    rows = [
        (
            f"elderly at intensity {a:g}",
            stylise_motion(model, motion, c.neutral_style, "walk", {"elderly": a, c.neutral_style: 1 - a}),
        )
        for a in (0.0, 0.3, 0.6, 1.0)
    ]
    filmstrip(rows, docs / "intensity-bandai2.png", title=f"Intensity (the paper's Fig. 5): {clip.name}")
    out["intensity"] = "intensity-bandai2.png"
    rows = [
        (name, stylise_motion(model, motion, c.neutral_style, "walk", w))
        for name, w in (
            ("elderly", {"elderly": 1.0}),
            ("elderly 0.5 + feminine 0.5", {"elderly": 0.5, "feminine": 0.5}),
            ("feminine", {"feminine": 1.0}),
        )
    ]
    filmstrip(rows, docs / "mixture-bandai2.png", title="A two-style mixture")
    out["mixture"] = "mixture-bandai2.png"
    zero, _ = load_generator(model_stem("zero initial states"))
    first = motion[:10]
    rows = [
        ("input, first 10 frames", first),
        ("full model -> elderly", stylise_motion(model, first, c.neutral_style, "walk", {"elderly": 1.0})),
        ("zero initial states -> elderly", stylise_motion(zero, first, c.neutral_style, "walk", {"elderly": 1.0})),
    ]
    filmstrip(
        rows,
        docs / "first-frames-bandai2.png",
        frames=10,
        title="The first 10 frames of a stream: learned vs zero initial states",
    )
    out["first frames"] = "first-frames-bandai2.png"
    return out


def measured(docs: Path, name: str, keep: tuple[str, ...], measure) -> dict:
    """``docs/NAME.json`` as measured before when ``name`` is in ``keep`` (its models and code
    unchanged since), else ``measure()``, written there."""
    path = docs / f"{name}.json"
    if name in keep:
        if not path.is_file():
            raise StyleERDError(f"--keep {name}: {path} has not been measured yet")
        return json.loads(path.read_text())
    figures = measure()
    atomic_write_text(path, json.dumps(figures, indent=1) + "\n")
    return figures


def write_report(
    docs: Path = Path("docs"),
    data_dir: str | None = None,
    bench_steps: int = 2000,
    bench_streams: tuple[int, ...] = STREAMS,
    progress=print,
    keep: tuple[str, ...] = (),
) -> Path:
    """``keep``: parts ("ablations", "bench") read from their JSON in ``docs`` instead of measured again."""
    docs.mkdir(parents=True, exist_ok=True)
    model, meta = load_generator()
    progress("quality of the shipped model ...")
    quality = evaluate_model(model, data_dir)
    progress("ablations ...")
    ablations = measured(docs, "ablations", keep, lambda: ablation_table(data_dir))
    epochs = shipped_budget()[1]
    atomic_write_text(docs / "ablations.md", markdown(ablations, epochs))
    progress("runtime figures ...")
    runtime = runtime_report(model, load_labeller()[0], data_dir)
    bench = measured(docs, "bench", keep, lambda: run_bench(model, bench_steps, bench_streams, progress=progress))
    plot(bench, docs / "throughput.png")
    progress("pictures ...")
    pics = pictures(docs, data_dir)
    per_style = " | ".join(
        f"{k} {v:.3f} ({quality['fmd_floor_per_style'][k]:.3f})" for k, v in quality["fmd_per_style"].items()
    )
    progress("rotations on other skeletons ...")
    rotations = rotation_report(model, meta["data"]["fps"], data_dir)
    write_rotations(rotations, docs / "rotations.md")
    sra = f"{100 * quality['sra']:.2f} %"
    fmd = f"{quality['fmd']:.3f} ({quality['fmd_floor']:.3f}); {quality['fmd_over_floor']:.2f} x the floor"
    responsive = f"{100 * quality['sra_first_10']:.1f} % / {100 * quality['sra_rest']:.1f} %"
    text = f"""# Results

Regenerated by `styleerd report` from the shipped models (`models/`) on the Bandai-Namco-2 test
split; every figure is printed by its own command as well (named in each section).

## The shipped model (`styleerd eval quality`)

| | value |
| --- | --- |
| SRA (transfers: neutral -> each style, styled -> neutral; {quality["transfers"]:,} windows) | {sra} |
| CRA | {100 * quality["cra"]:.2f} % |
| FMD (floor: two halves of the real test windows) | {fmd} |
| FMD per target style (floor) | {per_style} |
| responsiveness: SRA on the first 10 frames of each clip / after | {responsive} |
| responsiveness: FMD on the first 10 frames / after | {quality["fmd_first_10"]:.3f} / {quality["fmd_rest"]:.3f} |
| jitter (mean jerk of transfers / of real motion) | {quality["jitter_ratio"]:.2f} |
| reconstruction (target = input style) | {quality["rec_deg"]:.2f} degrees, {quality["rec_cm"]:.2f} cm |
| training | {training_minutes(meta["training"])} on a 2-core CPU |

## Ablations (the paper's Table 1; `styleerd eval ablations`)

{markdown(ablations, epochs)}

## Runtime (the paper's Table 2 and more; `styleerd bench`)

{table(bench)}
![throughput](throughput.png)

{online_section(runtime)}
{rotations_section(rotations)}
{actions_section(docs)}
{labels_section(docs)}
{recipes_section(docs)}
{added_styles_section(docs)}
## Pictures

![every style]({pics["every style"]})

![intensity]({pics["intensity"]})

![mixture]({pics["mixture"]})

![first frames]({pics["first frames"]})
"""
    path = docs / "RESULTS.md"
    atomic_write_text(path, text)
    return path


def training_minutes(training: dict) -> str:
    """The training time of a model's metadata, each stage when it was fine-tuned from another."""
    if "soup" in training:  # stages fine-tuned from one start, their weights averaged
        start = training_minutes(training["started_from"]["training"])
        stages = " and ".join(
            f"{s['training'].get('wall_minutes')} min ({s['training']['config']['name']})" for s in training["soup"]
        )
        return f"{start} + {stages}, each fine-tuning from it, their weights averaged (`styleerd soup`)"
    here = f"{training.get('wall_minutes')} min ({training['config']['name']})"
    base = training.get("started_from")
    if base is None:
        return here
    return f"{training_minutes(base['training'])}; then {here}, fine-tuning from it"


def online_section(runtime: dict) -> str:
    """The "Online behaviour" section of RESULTS.md from ``runtime_report``."""
    skate, switch, labels, raw = (
        runtime["foot_skate_cm_per_frame"],
        runtime["style_switch"],
        runtime["labels"],
        runtime["labels_raw"],
    )
    xia = "\n".join(
        f"| {clip} | {' / '.join(v[k] for k in ('1', '10', '30', 'end'))} |"
        for clip, v in runtime["xia_labels"].items()
    )
    after = lambda table, key: " / ".join(f"{100 * table[n][key]:.1f} %" for n in (1, 10, 30))
    pace = skate["root_speed_ratio_range"]
    rows = "\n".join(
        f"| {label} | {value} |"
        for label, value in (
            (
                (
                    "input labels inferred online, right after 1 / 10 / 30 frames (style; as the stylizer uses them: "
                    "unsure ones lean to neutral)"
                ),
                after(labels, "style"),
            ),
            ("the same, the labeller's own top label", after(raw, "style")),
            ("the same (content)", after(labels, "content")),
            (
                "foot skate while planted, cm/frame: input / raw output / cleaned output",
                (
                    f"{skate['input']:.3f} / {skate['raw_output']:.3f} / {skate['cleaned_output']:.3f} "
                    f"({skate['streams']} streams x {skate['frames']} frames)"
                ),
            ),
            (
                f"the same with `--root-speed` (root pace over the input's per stream: {pace[0]:.2f} to {pace[1]:.2f})",
                f"- / {skate['raw_output_root_speed']:.3f} / {skate['cleaned_output_root_speed']:.3f}",
            ),
            (
                (
                    f"largest joint move per frame around a style switch: no switch / blended over "
                    f"{switch['blend_frames']} frames / unblended (cm)"
                ),
                (
                    f"{switch['no_switch_cm']:.2f} / {switch['blended_cm']:.2f} / {switch['unblended_cm']:.2f} "
                    f"(p99 of normal motion {switch['normal_p99_cm']:.2f})"
                ),
            ),
        )
    )
    return f"""## Online behaviour (`styleerd eval-runtime`)

| | value |
| --- | --- |
{rows}

The input style the encoder is told for each xia-sample clip (another performer, another
skeleton, 120 fps; the labeller is trained on Bandai-Namco-2 with copies of each clip as other
performers and rigs would give it (proportions, speed, joint offsets, mirroring), then fine-tuned
with Bandai-Namco-1's and cmu-sample's clips; no xia-sample clip is in its training), after
1 / 10 / 30 frames / at the end. The neutral walk must read `normal`; the xia styles (angry,
depressed, sexy, strutting) are not the model's, and jumps (16) and punches (18) are contents
it never saw.

| clip | inferred style |
| --- | --- |
{xia}
"""


def _code(side: dict) -> str:
    code = side.get("code", "working tree")
    return "the working tree" if code == "working tree" else f"commit {code}"


def _training_runs(r: dict) -> str:
    """The two kept models' training runs, timed at the step times above (validation left out)."""
    if "training_ratio" not in r:
        return ""
    b, a = r["before"], r["after"]
    return (
        f" The kept models' whole runs at these step times: `{b['model']}` {b['epochs_trained']} epochs, "
        f"{b['training_min']:.1f} min; `{a['model']}` {a['epochs_trained']} epochs, {a['training_min']:.1f} min: "
        f"{r['training_ratio']:.2f} of the time."
    )


def _styles_read_paragraph(report: dict) -> str:
    """What the style recogniser reads on other performers' walks (``actions.read_as_target``), per
    pose path: the span of the mean over the styles, and the style least read."""
    feet, styles = report.get("feet", {}), report["styles"]
    outside = {n: r for n, r in feet.items() if not r["source"].startswith("bandai-namco-2")}
    if not outside or next(iter(outside.values()))["pose input"][styles[0]].get("read_as_target") is None:
        return ""

    def means(pose: str) -> list[float]:
        return [float(np.mean([r[pose][s]["read_as_target"] for s in styles])) for r in outside.values()]

    mine, net = means("pose input"), means("pose network")
    per_style = {s: float(np.mean([r["pose input"][s]["read_as_target"] for r in outside.values()])) for s in styles}
    least = min(per_style, key=per_style.get)
    return f"""
Whether a style shows on other performers' walks is also read by the project's style recogniser
(the table after "Feet and pace"): on the {len(outside)} walks of other performers and rigs, the
default pose's outputs are read as their target on {min(mine):.2f} to {max(mine):.2f} of their windows
(the mean over the styles; {least} on {per_style[least]:.2f} on average), the network's own pose's on
{min(net):.2f} to {max(net):.2f}. Where the network does not rebuild a performer's walk, the default path
turns the input's pose by the style's posture, an average pose: it carries what a style changes in the
pose, not what it changes in the timing (active's bounce).
"""


def actions_section(docs: Path) -> str:
    """Issue 35's section: the held-out action table (``styleerd eval actions``: docs/actions.*),
    and the shipped model on Bandai-Namco-2 with each pose path (``eval quality --pose``,
    ``eval streamed --pose``: docs/pose-quality.json, docs/pose-streamed.json), where they exist."""
    actions, quality, streamed = docs / "actions.md", docs / "pose-quality.json", docs / "pose-streamed.json"
    if not actions.is_file():
        return ""
    report = json.loads(actions.with_suffix(".json").read_text())
    clips = report["poses"]["input"]["clips"]
    swims = [r["cosine_body"] for c in clips.values() if c["action"] == "swim" for r in c["styles"].values()]
    xia = clips["xia depressed_18_000"]["styles"]["elderly"]
    posture = [r["model"][0] for a, row in report["performers"]["actions"].items() if a != "walk" for r in row.values()]
    span = lambda v: f"{min(v):.2f} to {max(v):.2f}"
    text = f"""## Any action, any performer: the input's pose plus the style's posture (`styleerd eval actions`)

Held-out clips of other performers, skeletons and actions, none of them in any training run (CMU
subjects 2 and 126 from cmu-sample on their Character Creator and ASF rigs, Bandai-Namco-1's
neutral actions, xia-sample's jump and punch), streamed through `transfer` as users run it, on their
own skeletons, beside Bandai-Namco-2 test walks. Pose `network` is the network's own pose (the
paper's output, and this project's until now); pose `input` (the default) keeps the network's pose
where it rebuilds the input and otherwise turns the input's own pose by the style's posture (its
change to the network's pose averaged over the training split's neutral walks, `styleerd posture`;
[Transfer and styles](guide/transfer.md#any-action-pose), "Any action"). Correlation: of the hands'
and feet's root-relative velocities, input against output (1 = the same action). Cosine and size:
the style's change (styled output minus identity output, per joint, in the body's heading frame,
averaged over the clip) against the same on the walks. A posture turns the input's joints towards
where the style moves them relative to the root along the body's own axes (up from the hips to the
head), so a swimmer's back bends as a walker's does; in the heading frame (up the world's) that
change points elsewhere on a body lying down, so the swims' cosines are the lowest of the main
table. For the clips under 0.7, a second table gives the same cosine in the body's own frame, and
the held-out actions' mean and worst: there the swims point as the walks ({span(swims)}). With the
posture laid in the heading frame, as it was until then, the swims read 0.23 to 0.86 in the heading
frame and -0.27 to 0.71 in the body's own; the three ways side by side are in
[Model](model.md#the-postures-offsets-along-the-bodys-own-axes) (`python
benchmarks/posture_frames.py`, measured at the input's own joints, as below).
The change is measured on the model's skeleton (input and outputs retargeted onto it), so that a
joint is the same point of the body on every rig. On xia-sample's and CMU subject 126's rigs (CMU's
ASF layout) the joints mapped to the model's Neck and both Shoulders start where the chest's joint
is (`OFFSET 0 0 0`): read there, a chest bent forward moved neither, and the chest counted three
more times against the walks' neck and shoulders. Read at the input's own joints, xia's punch into
elderly pointed as the walks at 0.64 ({xia["cosine"]:.2f} now), and its size was 0.74 of theirs
({xia["size_ratio"]:.2f} now).
Whether a style's change should point as on walks at all is measured on a real performer: on
Bandai-Namco-1's kept-back takes, the performer's own change on walk-back, dash, byebye and guide
points as their change on the walk at -0.21 to 0.71, and two takes of one walk agree at 0.18 to 0.96,
where the posture's points as the walks' at {span(posture)} ("The style's change as a performer makes
it" below; [Model](model.md#active-on-a-punch-and-what-a-real-performers-change-looks-like), with
how active came to show on the punches).
{_styles_read_paragraph(report)}
![a dance](actions-dance-short.png)

![a kick](actions-kick.png)

![a punch](actions-punch.png)

"""
    text += actions.read_text()
    if quality.is_file() and streamed.is_file():
        q, st = json.loads(quality.read_text()), json.loads(streamed.read_text())
        rows = ["| figure | pose network | pose input |", "| --- | ---: | ---: |"]
        for label, key, scale in (
            ("SRA", "sra", 100),
            ("CRA", "cra", 100),
            ("FMD", "fmd", 1),
            ("FMD / floor, worst style", "worst_fmd_over_floor", 1),
            ("CRA / ceiling, worst style", "worst_cra_of_ceiling", 100),
            ("jitter ratio", "jitter_ratio", 1),
        ):
            rows.append(f"| {label} | {scale * q['network'][key]:.3g} | {scale * q['input'][key]:.3g} |")
        for style in q["network"]["sra_per_style"]:
            rows.append(
                f"| {style}: SRA / CRA / FMD (floor {q['network']['fmd_floor_per_style'][style]:.3f}) | "
                + " | ".join(
                    f"{100 * q[p]['sra_per_style'][style]:.1f} / {100 * q[p]['cra_per_style'][style]:.1f} / "
                    f"{q[p]['fmd_per_style'][style]:.3f}"
                    for p in ("network", "input")
                )
                + " |"
            )
        for what in ("to_neutral_mean", "into_styles_mean"):
            rows.append(
                f"| streamed, {what.replace('_', ' ')} (labels given / inferred) | "
                + " | ".join(
                    f"{100 * st[p][what]['given']:.1f} / {100 * st[p][what]['inferred']:.1f}"
                    for p in ("network", "input")
                )
                + " |"
            )
        for source in st["network"]["to_neutral"]:
            rows.append(
                f"| streamed, {source} -> normal (given / inferred) | "
                + " | ".join(
                    f"{100 * st[p]['to_neutral'][source]['given']:.1f} / "
                    f"{100 * st[p]['to_neutral'][source]['inferred']:.1f}"
                    for p in ("network", "input")
                )
                + " |"
            )
        text += (
            """
### The same model on Bandai-Namco-2's test split, each pose path

`styleerd eval quality --pose network|input` (24-frame test windows from fresh states: percentages,
FMD) and `styleerd eval streamed --pose network|input` (whole test clips streamed as `transfer` runs
them: the share of windows read as the target), kept in `docs/pose-quality.json` and
`docs/pose-streamed.json`.

"""
            + "\n".join(rows)
            + "\n"
        )
    clips = docs / "clip-styles.md"
    if clips.is_file():
        text += """
### A second judge of another design: whole clips (`styleerd eval clip-styles`)

The recognisers above read 24-frame windows of every feature channel with a convolution. This one
is a GRU over whole clips that reads joint positions and the root's velocity only (no rotation),
trained on the training takes (`models/clip-recogniser-bandai2`); it reads each test take
streamed through `transfer` (the default pose, labels inferred online) as one clip, also with
`--root-speed` and with `--no-cleanup`, and the neutral takes into each style per content with the
foot cleanup and without it: the cleanup holds the output's planted feet where the input's are, and
where it straightened a style's bent legs on the spot (an active performer's bounce while raising a
hand) the style was gone (`docs/model.md`, "The foot cleanup keeps the output's own legs"). Counts
of takes.

""" + clips.read_text()
    return text


def labels_section(docs: Path) -> str:
    """The labeller on other performers' clips (``styleerd eval labels``: docs/labels.*), before
    and after it was fine-tuned with such clips (docs/labels-scratch.md), where they exist."""
    labels, before = docs / "labels.md", docs / "labels-scratch.md"
    if not labels.is_file():
        return ""
    text = """## The labeller on other performers (`styleerd eval labels`)

What the online labeller tells the encoder when `--input-style` is not given, on clips of other
performers and skeletons that no labeller trains on: xia-sample (its `old` is the model's
`elderly`; angry, childlike, depressed, proud, sexy and strutting are no style of the model's),
cmu-sample's held-out subjects (all neutral) and Bandai-Namco-1's kept-back clips (nine of its
styles are not the model's). A confident wrong style (told with weight 0.9 or more, neither the
clip's own nor neutral) is subtracted from the input by the network; an unsure one leans to
neutral, and so does one where the labeller's state is unlike its training streams' (the model
file's `familiar.*`, [Where the labeller knows what it sees](model.md#where-the-labeller-knows-what-it-sees)).
The shipped labeller (`configs/labeller-outside.yaml`) is the one trained on Bandai-Namco-2 alone
(`models/labellers/labeller-bandai2-scratch`) fine-tuned with other performers' clips:
Bandai-Namco-1's, its styles the model lacks taught to read as unsure, and cmu-sample's other
subjects.

"""
    text += labels.read_text()
    if before.is_file():
        text += "\nThe labeller trained on Bandai-Namco-2 alone, on the same clips:\n\n" + before.read_text()
    return text + "\n"


def recipes_section(docs: Path) -> str:
    """Issue 16's section: the recipes side by side (``styleerd eval recipes``: docs/recipes.*)
    and the training step of two recipes timed side by side (``benchmarks/bench_train_step.py
    --json docs/train-step.json``), where they exist."""
    recipes, speed = docs / "recipes.md", docs / "train-step.json"
    if not recipes.is_file():
        return ""
    text = """## Recipes side by side: realism per style, content, back to neutral (`styleerd eval recipes`)

Every kept model (the shipped one, the recipes under `models/recipes/`, the ablations), judged
by the same recognisers, labeller and FMD extractor on the test split. FMD / floor per target
style: the transfers into the style against its real test windows, over the FMD of two halves
of those real windows; CRA / ceiling per target style: content read on the transfers over
content read on their inputs. Back to neutral / into styles: every test clip streamed frame by
frame as `transfer` runs it (labels given / inferred online), the output cut into 24-frame
windows as it plays and read by the style recogniser; with `--root-speed` the root moves at the
network's pace. ± one standard deviation over 200 bootstrap resamples of the transfers. The
inferred labels here are the labeller's trained on Bandai-Namco-2 alone
(`models/labellers/labeller-bandai2-scratch`, shipped until it was fine-tuned with other
performers' clips; on Bandai-Namco-2's test clips both read the style right after 10 and after
30 frames on every clip: `styleerd/models/labeller-bandai2.json`).

"""
    text += recipes.read_text() + "\n![FMD against CRA, per recipe and per style](recipes.png)\n\n"
    if speed.is_file():
        r = json.loads(speed.read_text())
        parts = list(r["before"]["parts_ms"]) + [k for k in r["after"]["parts_ms"] if k not in r["before"]["parts_ms"]]
        rows = "\n".join(
            f"| {k} | {r['before']['parts_ms'].get(k, 0):.1f} | {r['after']['parts_ms'].get(k, 0):.1f} |" for k in parts
        )
        text += f"""### A training step, two recipes side by side (`benchmarks/bench_train_step.py`)

The trainer's own step (`train.trainer.train_step`) of `{r["before"]["config"]}` on the trainer's
code at {_code(r["before"])} and of `{r["after"]["config"]}` on {_code(r["after"])}, each in its own process,
the two taking turns step by step in one run on the same batches (batch {r["before"]["batch"]} and
{r["after"]["batch"]}, {r["threads"]} threads, {r["steps"]} steps each), so both see the same machine;
each part's time per step, averaged over the steps (R1 runs
on every 4th step, the cycle pass on every `cyc_every`-th).

| part (ms) | before | after |
| --- | --- | --- |
{rows}
| step | {r["before"]["step_ms"]:.1f} | {r["after"]["step_ms"]:.1f} |
| epoch (s) | {r["before"]["epoch_s"]:.1f} | {r["after"]["epoch_s"]:.1f} |

{r["speedup"]:.2f} x the training windows per minute.{_training_runs(r)}

"""
    return text


def added_styles_section(docs: Path) -> str:
    """The sections on styles the shipped model never saw, from ``docs/unseen-styles.json``
    (``benchmarks/unseen_styles.py``) and ``docs/bandai12.json`` (``styleerd evaluate --model
    styleerd-bandai12 --recognisers recognisers-bandai12 --json docs/bandai12.json``), where they exist."""
    text = ""
    unseen, b12 = docs / "unseen-styles.json", docs / "bandai12.json"
    if unseen.is_file():
        r = json.loads(unseen.read_text())
        pct = lambda v: f"{100 * v:.1f} %"
        rows = []
        for style, v in r["styles"].items():
            start = v.get("from_start")
            cells = [
                f"{v['minutes']:.1f}",
                *(pct(x[f"{k}_played"]) for x in (v["added"], v["none"]) for k in ("sra", "cra")),
            ]
            cells += [
                f"{v['added']['fmd']:.3f}",
                f"{v['none']['fmd']:.3f}",
                f"{v['fmd_real_adaptation_vs_kept_back']:.3f}",
                pct(v["recogniser_ceiling"]),
            ]
            cells += [f"{pct(start['sra_played'])} / {pct(start['cra_played'])} / {start['fmd']:.3f}" if start else "-"]
            rows.append(f"| {style} | " + " | ".join(cells) + " |")
        trained = "\n".join(
            f"| {k} | {pct(v['sra_played'])} | {pct(v['cra_played'])} | {v['fmd']:.3f} |"
            for k, v in r.get("trained_styles", {}).items()
        )
        start_note = (
            f"`{r['from_start_model']['model']}` ({r['from_start_model']['training_minutes']} min of training)"
            if "from_start_model" in r
            else "not yet trained"
        )
        reads = {", ".join(v.get("critic_reads") or ["positions", "velocities"]) for v in r["styles"].values()}
        critic = _critic_comparison(r, docs / "unseen-styles-positions-critic.json")
        columns = ("style", "minutes", "SRA added", "CRA added", "SRA none", "CRA none", "FMD added", "FMD none")
        columns += ("FMD real vs real", "SRA ceiling", "from the start")
        header = "| " + " | ".join(columns) + " |\n" + "| --- " * len(columns) + "|"
        text += (
            f"""## Styles the shipped model never saw: `styleerd add-style` (`benchmarks/unseen_styles.py`)

Per Bandai-Namco-1 style absent from Bandai-Namco-2: six of its eleven clips (walk 001, run,
walk-left, walk-right, bow, bye) added it to the shipped model with `add-style` (1,200 steps,
minutes of the whole command on this 2-core machine, sharing it with other work; its critic
read {" / ".join(sorted(reads))}, as the model's own); the other
five (walk 002, dash, walk-back, byebye, guide) were kept back. Judged on {r["content"]["windows"]}
neutral Bandai-Namco-2 test windows of walk and run, transferred into the style, as they play
(the output poses on the input's root path, velocities from the played positions): SRA by a
15-style recogniser trained on the kept-back Bandai-1 clips only ("ceiling": its accuracy on
the style's adaptation clips, real motion it never saw), CRA by the shipped content recogniser,
FMD (shipped extractor) against the kept-back locomotion clips of the style (walk 002, dash,
walk-back), beside the FMD between the style's own adaptation and kept-back locomotion clips
(real against real). "None" is the neutral input unchanged; "from the start" is {start_note},
trained with the same six clips of every Bandai-1 style (SRA / CRA / FMD).
{critic}
{header}
"""
            + "\n".join(rows)
            + f"""

The same judge on the shipped model's own styles (trained on hundreds of Bandai-Namco-2 clips),
under their Bandai-1 names: how far one dataset's style reads as the other's.

| shipped style (Bandai-1 name) | SRA | CRA | FMD |
| --- | --- | --- | --- |
{trained}

Every old style's output is bit-identical after `add-style` on the torch, numpy and numba
backends (`tests/test_add_style.py`).

![added styles](added-styles.png)

"""
        )
    if b12.is_file():
        r = json.loads(b12.read_text())
        per = "\n".join(
            f"| {k} | {100 * v['sra']:.1f} % | {100 * v['cra']:.1f} % | {v['transfers']} |"
            for k, v in r["per_target"].items()
        )
        text += f"""## The 16-style model (`styleerd-bandai12`, `configs/{r["config"]}.yaml`)

Bandai-Namco-1 and -2 as one dataset (`bandai-namco-1+2`: Bandai-1's old, tired and
masculinity are Bandai-2's elderly, exhausted and masculine; active, feminine and normal are
the same names; 15 Bandai-1 styles and Bandai-2's youthful), {r["training_minutes"]} min of training.
`styleerd evaluate --model styleerd-bandai12 --recognisers recognisers-bandai12` on its test split
({r["windows"]:,} windows: Bandai-2's test takes and every Bandai-1 style's five kept-back clips),
with recognisers trained on its training split: SRA {100 * r["sra"]:.1f} %
({100 * r["sra_of_ceiling"]:.1f} % of the recogniser's {100 * r["style_ceiling"]:.1f} % on real windows),
CRA {100 * r["cra"]:.1f} % ({100 * r["cra_of_ceiling"]:.1f} % of {100 * r["content_ceiling"]:.1f} %),
reconstruction {r["rec_deg"]:.2f} degrees / {r["rec_cm"]:.2f} cm.

| target style | SRA | CRA | transfers |
| --- | --- | --- | --- |
{per}

{actions_summary(docs / "actions-bandai12.json", "styleerd-bandai12")}"""
    return text


def actions_summary(path: Path, model: str) -> str:
    """Per target style, the held-out actions' mean against the walks' (``styleerd eval actions --model M
    --out``'s JSON): correlation, the change's cosine in the heading and the body's frame and its size."""
    if not path.is_file():
        return ""
    r = json.loads(path.read_text())
    table = "#any-action-any-performer-the-inputs-pose-plus-the-styles-posture-styleerd-eval-actions"
    text = f"""On the held-out actions of other performers (`styleerd eval actions --model {model} --out
docs/{path.with_suffix(".md").name}`, the clips of [the table above]({table})): the identity transfer and, per
style, the actions' mean against the walks' mean (velocity correlation; the style's change: cosine in the
heading frame / the body's frame, size over the walks').
"""
    for pose, p in r["poses"].items():
        walks, actions = p["summary"]["walks"], p["summary"]["actions"]
        error, corr = actions["identity_error_cm"], actions["identity_correlation"]
        text += f"""
Pose `{pose}`: identity {error["mean"]:.1f} cm (worst {error["worst"]:.1f}), correlation {corr["mean"]:.2f}
(worst {corr["worst"]:.2f}) on {actions["clips"]} clips; on {walks["clips"]} walks
{walks["identity_error_cm"]["mean"]:.1f} cm, {walks["identity_correlation"]["mean"]:.2f}.

| style | correlation: actions / walks | cosine: heading / body | size |
| --- | --- | --- | --- |
"""
        for style, a in actions["styles"].items():
            w = walks["styles"][style]
            text += (
                f"| {style} | {a['correlation']:.2f} / {w['correlation']:.2f} | "
                f"{a['cosine']:.2f} / {a['cosine_body']:.2f} | {a['size_ratio']:.2f} |\n"
            )
    for picture in sorted(path.parent.glob(f"{path.stem}-*.png")):  # the filmstrips ``eval actions`` draws
        text += f"\n![{model}: {picture.stem[len(path.stem) + 1 :]}]({picture.name})\n"
    return text + "\n"


def _critic_comparison(r: dict, other_path: Path) -> str:
    """A paragraph setting the added styles beside the same run with a critic of positions and
    velocities only (``benchmarks/unseen_styles.py --critic-positions-only``), where measured."""
    if not other_path.is_file():
        return ""
    other = json.loads(other_path.read_text())["styles"]
    both = [k for k in r["styles"] if k in other]
    mean = lambda runs, key: float(np.mean([runs[k]["added"][key] for k in both]))
    ours = r["styles"]
    lower = sum(ours[k]["added"]["fmd"] < other[k]["added"]["fmd"] for k in both)
    return f"""
Against the same run with a critic of positions and velocities only (`benchmarks/unseen_styles.py
--critic-positions-only`, `{other_path.name}`), mean over the {len(both)} styles: SRA
{100 * mean(ours, "sra_played"):.1f} % against {100 * mean(other, "sra_played"):.1f} %,
CRA {100 * mean(ours, "cra_played"):.1f} % against {100 * mean(other, "cra_played"):.1f} %,
FMD {mean(ours, "fmd"):.3f} against {mean(other, "fmd"):.3f} (lower for {lower} of {len(both)} styles).
"""


def rotations_section(report: dict) -> str:
    """The "Rotations on other skeletons" section of RESULTS.md from ``rotation_report``."""
    return f"""## Rotations on other skeletons, twist included (`styleerd eval rotations`)

Per input, the joint whose global rotation moves most (median over frames) between input and
output, split into swing (where the bone points) and twist (its roll about itself, which moves
no joint and shows only on a skinned body). Round trip: target style = the input's style, so
ideally nothing changes; what remains is the model's reconstruction error (on its own skeleton
for the Bandai-Namco-2 rows). The five generated rigs move exactly alike (T-pose, A-pose,
centimetres, metres, Blender names and proportions, joint frames rolled about their bones): the
rig does not change the result. Before bone frames were fixed, the same round trip rolled
RightUpLeg 174 degrees on the xia neutral walk and 173 on the demo walk. The xia toes are bent
25-68 degrees through its clips, far from any Bandai-Namco toe, and jumps (16) and punches (18)
are contents the model never saw: those are the model's limits, not the mapping's.

{markdown_rotations(report)}"""
