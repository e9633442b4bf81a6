"""Every rig family a user brings, with no joint map: does it map, do rotations come back, is
the written file valid?

The demo walk on generated rigs of each naming family and quirk (``rig_families``), plus the
real RobotExpressive character and cmu-sample's two rigs when ``../shared/data`` is there. Per
rig: mapped with no map; the mapping's round trip (model and back), worst joint's global
rotation angle, swing and twist; a transfer at intensity 0 (target = the input's style, given),
worst mapped joint's angle against the input and how far the lowest foot goes below the
input's lowest (cm; metre rigs scaled); and the
rig written as a skinned .glb, transferred glb -> glb, checked by the Khronos glTF validator
(errors / warnings of the output, the input's beside them). Writes docs/rig-families.json and
docs/rig-families.md.

    python benchmarks/rig_families.py [--data DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from styleerd.data.datasets import data_root, unpack
from styleerd.errors import StyleERDError
from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import read_gltf, write_glb
from styleerd.motion.humanoid import body_parts
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.procedural import rig_families
from styleerd.motion.retarget import joint_map, to_source, to_target
from styleerd.runtime.offline import TransferOptions, transfer_file, transfer_motion

VALIDATE = """
const fs = require('fs');
const validator = require(process.argv[2]);
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[3])), {maxIssues: 1000})
  .then(r => console.log(JSON.stringify([r.issues.numErrors, r.issues.numWarnings])),
        e => { console.error(String(e)); process.exit(1); });
"""
VALIDATOR = ROOT / "node_modules" / "gltf-validator"


def validated(path: Path) -> list[int] | None:
    """[errors, warnings] of the Khronos validator, or None where node or the validator is missing."""
    if not VALIDATOR.exists() or not shutil.which("node"):
        return None
    script = path.with_name("validate.cjs")
    script.write_text(VALIDATE)
    out = subprocess.run(["node", str(script), str(VALIDATOR), str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def worst_angle(a, b, joints=None) -> float:
    """Largest angle (degrees) between the two motions' global joint rotations."""
    ga, _ = forward_kinematics(a.rotations, a.positions, a.skeleton.parents)
    gb, _ = forward_kinematics(b.rotations, b.positions, b.skeleton.parents)
    angles = np.degrees(quat.angle_between(ga, gb))
    return float(angles[:, joints].max() if joints is not None else angles.max())


def lowest_foot(m, parts) -> float:
    _, g = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    return float(g[:, [parts[p] for p in ("left_foot", "right_foot") if p in parts], 1].min())


def measure(model, name: str, motion, folder: Path) -> dict:
    """One rig's row."""
    row: dict = {"rig": name, "joints": motion.skeleton.n_joints}
    try:
        jm = joint_map(model.skeleton, motion.skeleton, None, model.stats().reference, motion.rotations[0])
    except ValueError as e:
        return row | {"mapped": False, "why": str(e).splitlines()[0][:200]}
    row["mapped"] = True
    row["round_trip_deg"] = worst_angle(motion, to_source(to_target(motion, jm), jm, motion))
    options = TransferOptions({"normal": 1.0}, input_style="normal", content="walk")
    out = transfer_motion(motion, model, model.meta["data"]["fps"], options)
    mapped = sorted({s for _, s in jm.pairs})
    parts = body_parts(motion.skeleton, motion.rotations[0])
    unit = 100.0 if jm.scale > 10 else 1.0  # centimetres
    row["intensity0_worst_deg"] = worst_angle(motion, out, mapped)
    row["feet_below_input_cm"] = unit * (lowest_foot(motion, parts) - lowest_foot(out, parts))
    glb = folder / f"{len(list(folder.glob('*.glb')))}.glb"
    write_glb(glb, motion, mesh=True)
    transfer_file(glb, glb.with_suffix(".out.glb"), model, model.meta["data"]["fps"], options)
    row["validator_in"], row["validator_out"] = validated(glb), validated(glb.with_suffix(".out.glb"))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="data folder (default ../shared/data or $STYLEERD_DATA)")
    args = parser.parse_args()
    model = load_generator_weights()
    rigs = [(name, m[:150]) for name, (m, _) in rig_families().items()]
    try:
        root = data_root(args.data)
        rigs.append(
            (
                "RobotExpressive.glb, 'Walking' (real)",
                read_gltf(root / "characters" / "RobotExpressive.glb", "Walking").motion,
            )
        )
        cmu = unpack(root / "cmu-sample.tar.xz") / "cmu-sample"
        for folder, label in (("iclone", "Character Creator"), ("asf-names", "CMU ASF names")):
            clip = min((cmu / folder).glob("*.bvh"))
            rigs.append((f"cmu-sample {folder}/{clip.name}: {label} (real)", bvh.read(clip)[:150]))
    except (StyleERDError, OSError) as e:
        print(f"real rigs left out: {e}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, motion in rigs:
            rows.append(measure(model, name, motion, Path(tmp)))
            print(json.dumps(rows[-1]))
    (ROOT / "docs" / "rig-families.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [
        "Every rig mapped with no joint map (`python benchmarks/rig_families.py`). Round trip: the mapping to the",
        "model and back, worst joint's global rotation (swing and twist). Intensity 0: a transfer with the",
        "target style the input's own, worst mapped joint against the input (the model's own reconstruction",
        "error; the same on every rig when the mapping is right). Feet: how far the output's lowest foot",
        "joint goes below the input's (cm). Validator: the Khronos glTF validator's errors / warnings on the",
        "rig written as a skinned .glb and on its transfer.",
        "",
        "| rig | joints | mapped with no map | round trip (deg) | intensity 0 (deg) | feet below, cm | validator |",
        "| --- | ---: | --- | ---: | ---: | --- | --- |",
    ]
    for r in rows:
        if not r["mapped"]:
            lines.append(f"| {r['rig']} | {r['joints']} | no: {r['why']} | | | | |")
            continue
        v = [("not run" if x is None else f"{x[0]} / {x[1]}") for x in (r["validator_in"], r["validator_out"])]
        feet = f"{r['feet_below_input_cm']:.1f}"
        lines.append(
            f"| {r['rig']} | {r['joints']} | yes | {r['round_trip_deg']:.1e} | {r['intensity0_worst_deg']:.2f} "
            f"| {feet} | in {v[0]}, out {v[1]} |"
        )
    (ROOT / "docs" / "rig-families.md").write_text("# Rig families\n\n" + "\n".join(lines) + "\n")
    print("wrote docs/rig-families.json and docs/rig-families.md")


if __name__ == "__main__":
    main()
