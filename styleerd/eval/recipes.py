"""Training recipes side by side (issue 16): every kept model judged by the same recognisers,
labeller and FMD extractor on the test split; realism (FMD over its floor) against content
kept (CRA over its ceiling) per target style, and transfers back to neutral per source style
as users run them (labels given and inferred). Writes a JSON, a Markdown table and the
trade-off plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.eval.ablations import ABLATIONS, model_stem, trained
from styleerd.model import checkpoint as ckpt
from styleerd.models import shipped_styles
from styleerd.train.validation import CRA_BAR, FMD_BAR, style_ratios

RECIPES_DIR = (
    Path(__file__).resolve().parents[2] / "models" / "recipes"
)  # research models: in a checkout, not in the package


def recipe_models() -> dict[str, Path | None]:
    """Name -> model stem (None: the shipped model): the shipped model, the recipes kept
    under models/recipes/ and the ablations."""
    models: dict[str, Path | None] = {"shipped": None}
    styles = shipped_styles()
    models.update(
        {
            p.stem: p.with_suffix("")
            for p in sorted(RECIPES_DIR.glob("*.safetensors"))
            if tuple(json.loads(p.with_suffix(".json").read_text())["config"]["styles"]) == styles
        }
    )  # the shipped model's styles: the 16-style models are judged by their own recognisers (`styleerd evaluate`)
    models.update(
        {f"ablation: {name}": model_stem(name) for name in ABLATIONS if name != "full" and trained(name)}
    )  # full: a row of its own (shipped, or a recipe)
    return models


def per_style(quality: dict) -> dict[str, dict[str, float]]:
    """Per target style: FMD / floor and CRA / ceiling, rounded for the tables."""
    fmd, cra = style_ratios(quality)
    return {k: {"fmd_over_floor": round(fmd[k], 2), "cra_of_ceiling": round(cra[k], 4)} for k in fmd}


def neutralisation(streamed: dict, neutral: str) -> dict:
    """Per source style, the share of windows of its transfer back to ``neutral`` read as
    ``neutral`` (labels given / inferred), beside the transfers into styles."""
    t = streamed["transfers"]
    back = {
        s: {"given": v[neutral]["given"]["sra"], "inferred": v[neutral]["inferred"]["sra"]}
        for s, v in t.items()
        if s != neutral
    }
    into = t[neutral]

    def mean(rows, how):
        return round(float(np.mean([r[how]["sra"] for r in rows])), 4)

    return {
        "to_neutral": back,
        "to_neutral_mean": {
            how: round(float(np.mean([v[how] for v in back.values()])), 4) for how in ("given", "inferred")
        },
        "into_styles_mean": {how: mean(into.values(), how) for how in ("given", "inferred")},
        "into_styles": {s: {how: v[how]["sra"] for how in ("given", "inferred")} for s, v in into.items()},
    }


def recipe_table(data_dir: str | None = None, names: list[str] | None = None) -> dict:
    from styleerd.eval.metrics import evaluate_model, runtime_transfers

    style_rec, content_rec, _ = ckpt.load_recognisers()
    labeller, _ = ckpt.load_labeller()
    rows = {}
    for name, stem in tqdm([(n, s) for n, s in recipe_models().items() if names is None or n in names], desc="recipes"):
        model, meta = ckpt.load_generator(stem)
        q = evaluate_model(model, data_dir)
        training = meta["training"]
        stages = [s["training"] for s in training.get("soup", [])] or [
            training
        ]  # a soup: the steps of every stage averaged
        rows[name] = {
            "model": "shipped" if stem is None else str(stem.relative_to(RECIPES_DIR.parents[1])),
            "config": training["config"]["name"],
            "minutes": training.get("wall_minutes") or training["best"].get("minutes"),
            "steps": sum(t["best"].get("steps") or 0 for t in stages),
            "quality": q,
            "per_style": per_style(q),
        }
        if not name.startswith("ablation"):  # the ablations: realism and content only (their own table has the rest)
            for key, speed in (("neutralisation", False), ("neutralisation_root_speed", True)):
                rows[name][key] = neutralisation(
                    runtime_transfers(model, labeller, style_rec, content_rec, data_dir, root_speed=speed),
                    model.config.neutral_style,
                )
    return rows


def _label_where_free(ax, labels: list[tuple[str, float, float]], fontsize: float = 8) -> None:
    """Each ``(text, x, y)`` written beside its point (to its left in the right third of the axes), in
    the order given, unless it would overlap a label already written or leave the axes: the first
    ones are the ones that matter."""
    fig = ax.figure
    fig.canvas.draw()
    renderer, taken, inside = fig.canvas.get_renderer(), [], ax.get_window_extent()
    for text, x, y in labels:
        right = ax.transData.transform((x, y))[0] > inside.x0 + 0.65 * inside.width  # written to the point's left
        t = ax.annotate(
            text,
            (x, y),
            textcoords="offset points",
            xytext=(-5 if right else 5, 4),
            ha="right" if right else "left",
            fontsize=fontsize,
        )
        box = t.get_window_extent(renderer).expanded(1.05, 1.15)
        if any(box.overlaps(other) for other in taken) or not inside.contains(box.x0, box.y0) or box.y1 > inside.y1:
            t.remove()
        else:
            taken.append(box)


def tradeoff_plot(rows: dict, path: Path) -> None:
    """Left: every recipe's pooled FMD / floor against CRA / ceiling. Right: the same per target
    style, the shipped model's styles named and the other recipes' styles grey, named where they
    miss a limit. The issue's limits dashed. Labels that would overlap are left out (the table
    has every figure), the shipped model's and those outside the limits first."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 6))
    for ax in (a, b):
        ax.axvline(FMD_BAR, ls="--", c="grey")
        ax.axhline(CRA_BAR, ls="--", c="grey")
        ax.set_xscale("log")
        ax.grid(alpha=0.3)
    outside = lambda x, y: x > FMD_BAR or y < CRA_BAR
    points = []
    for name, r in rows.items():
        q = r["quality"]
        x, y = q["fmd_over_floor"], q["cra"] / q["content_ceiling"]
        shipped = name == "shipped"
        a.errorbar(
            x,
            y,
            xerr=q["spread"]["fmd"] / q["fmd_floor"],
            yerr=q["spread"]["cra"] / q["content_ceiling"],
            fmt="*" if shipped else "o",
            ms=14 if shipped else 5,
            c="crimson" if shipped else ("grey" if name.startswith("ablation") else "tab:blue"),
            capsize=3,
            zorder=3 if shipped else 2,
        )
        points.append((0 if shipped else 1 if outside(x, y) else 2, name, x, y))
    a.set(
        xlabel="FMD / floor (lower is more real)",
        ylabel="CRA / ceiling (content kept)",
        title="Recipes (bars: bootstrap spread; grey: ablations; star: shipped)",
    )
    styled = []
    for name, r in rows.items():
        if name.startswith("ablation"):
            continue
        shipped = name == "shipped"
        for style, v in r["per_style"].items():
            x, y = v["fmd_over_floor"], v["cra_of_ceiling"]
            b.scatter(x, y, marker="*" if shipped else "o", s=140 if shipped else 14, c="crimson" if shipped else "0.6")
            if shipped or outside(x, y):
                styled.append((0 if shipped else 1, style if shipped else f"{name}: {style}", x, y))
    b.set(
        xlabel="FMD / floor per target style",
        ylabel="CRA / ceiling per target style",
        title="Per target style (stars: shipped; named grey: outside a limit)",
    )
    fig.tight_layout()
    _label_where_free(a, [(n, x, y) for _, n, x, y in sorted(points, key=lambda p: p[0])])
    _label_where_free(b, [(n, x, y) for _, n, x, y in sorted(styled, key=lambda p: p[0])], fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _streamed_cells(r: dict) -> str:
    if "neutralisation" not in r:
        return " - | - | - "
    n, ns = r["neutralisation"], r["neutralisation_root_speed"]

    def pair(v: dict) -> str:
        return f"{100 * v['given']:.1f} / {100 * v['inferred']:.1f} %"

    return (
        f"{pair(n['to_neutral_mean'])} | {pair(n['into_styles_mean'])} | {pair(ns['to_neutral_mean'])}; "
        f"{pair(ns['into_styles_mean'])}"
    )


def markdown(rows: dict) -> str:
    lines = [
        (
            "| model | config | minutes | steps to the best epoch | FMD / floor | CRA / ceiling | SRA | worst style "
            "FMD / floor | worst style CRA / ceiling "
            "| back to neutral, given / inferred | into styles, given / inferred | the same with --root-speed |"
        ),
        "|" + " --- |" * 12,
    ]
    for name, r in rows.items():
        q, ps = r["quality"], r["per_style"]
        worst_f = max(ps, key=lambda k: ps[k]["fmd_over_floor"])
        worst_c = min(ps, key=lambda k: ps[k]["cra_of_ceiling"])
        lines.append(
            f"| {name} | {r['config']} | {r['minutes']} | {r['steps']} "
            f"| {q['fmd_over_floor']:.2f} (± {q['spread']['fmd'] / q['fmd_floor']:.2f}) | "
            f"{100 * q['cra'] / q['content_ceiling']:.1f} % (± {100 * q['spread']['cra'] / q['content_ceiling']:.1f}) "
            f"| {100 * q['sra']:.1f} % | {worst_f} {ps[worst_f]['fmd_over_floor']:.2f} | {worst_c} "
            f"{100 * ps[worst_c]['cra_of_ceiling']:.1f} % "
            f"| {_streamed_cells(r)} |"
        )
    lines.append("")
    for name, r in rows.items():
        if name.startswith("ablation"):
            continue
        ps = r["per_style"]
        lines += [
            (
                f"**{name}** per target style (FMD / floor, CRA / ceiling) and, labels given / inferred, back to "
                "neutral per source style and into each style:"
            ),
            "",
        ]
        lines.append("| | " + " | ".join(ps) + " |")
        lines.append("|" + " --- |" * (len(ps) + 1))
        lines.append("| FMD / floor | " + " | ".join(f"{v['fmd_over_floor']:.2f}" for v in ps.values()) + " |")
        lines.append(
            "| CRA / ceiling | " + " | ".join(f"{100 * v['cra_of_ceiling']:.1f} %" for v in ps.values()) + " |"
        )
        for key, how in (("neutralisation", ""), ("neutralisation_root_speed", ", --root-speed")):
            n = r[key]
            for what, rates in ((f"back to neutral{how}", n["to_neutral"]), (f"into the style{how}", n["into_styles"])):
                lines.append(
                    f"| {what} | "
                    + " | ".join(
                        f"{100 * rates[k]['given']:.1f} / {100 * rates[k]['inferred']:.1f} %" if k in rates else ""
                        for k in ps
                    )
                    + " |"
                )
        lines.append("")
    return "\n".join(lines) + "\n"
