"""Where a training step's time goes, and two recipes side by side in one run.

    python benchmarks/bench_train_step.py [--steps 40] [--batch 32] [--threads 2]
        [--before configs/bandai2-content.yaml] [--after configs/bandai2-fast.yaml]

Times each part of a step (the trainer's losses, weights from each config) on real
Bandai-Namco-2 windows. Steps of the two recipes alternate, so both see the same machine
(its speed drifts by 2x between sessions); "before" also runs the reconstruction and the
transfer as one batch of 2B through the whole generator, as the trainer did until issue 16,
"after" shares their encoding (``StyleERD.forward_targets``). Prints the median of every
part, the step and epoch time of each recipe and their ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from styleerd.atomic import atomic_write_text
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.discriminator import Discriminator
from styleerd.train import losses
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import make_generator, setup

R1 = "R1 penalty (every 4th step)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--before", default="configs/bandai2-content.yaml")
    ap.add_argument("--after", default="configs/bandai2-fast.yaml")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    recipes = {"before": TrainConfig.from_yaml(args.before, batch_size=args.batch), "after": TrainConfig.from_yaml(args.after, batch_size=args.batch)}
    s = setup(recipes["after"], None, progress=False)
    torch.manual_seed(0)
    G = make_generator(recipes["after"], s)
    J, L, B = G.config.n_joints, G.layout, args.batch
    D = Discriminator(6 * J, len(s.data.styles), len(s.data.contents), recipes["after"].window)
    C = WindowClassifier(10 * J, len(s.data.contents), instance_norm=True).requires_grad_(False)
    opt_g, opt_d = torch.optim.Adam(G.parameters()), torch.optim.Adam(D.parameters())
    rng = np.random.default_rng(0)
    parts: dict[str, dict[str, list[float]]] = {name: {} for name in recipes}

    def step(name: str, config: TrainConfig, i: int) -> None:
        times = parts[name]

        def tick(part: str, t0: float) -> float:
            t = time.perf_counter()
            times.setdefault(part, []).append(t - t0)
            return t

        rows = rng.choice(len(s.train.starts), B)
        t = time.perf_counter()
        x = s.data.gather(s.train.starts[rows])
        st, ct = s.data.onehot_style(s.train.style[rows]), s.data.onehot_content(s.train.content[rows])
        tgt = s.data.onehot_style(rng.integers(0, len(s.data.styles), B))
        t = tick("batch gather", t)
        if name == "before":
            rot, vel, _ = G(torch.cat([x, x]), torch.cat([st, st]), torch.cat([ct, ct]), torch.cat([st, tgt]))
        else:
            rot, vel = G.forward_targets(x, st, ct, torch.cat([st, tgt]))
        t = tick("generator forward (B + B)", t)
        ch = G.motion_channels(rot, vel)
        t = tick("forward kinematics + channels", t)
        real = x[..., : 10 * J]
        loss = losses.reconstruction_loss(rot[:B], G.raw_rotations(x), ch[:B], real, L)
        loss = loss + config.w_adv * losses.generator_adversarial(D(ch[B:, :, L.positions.start :], tgt, ct))
        loss = loss + config.w_per * losses.perceptual(C, real, ch[B:])
        loss = loss + config.w_cls * losses.content_classification(C, ch[B:], torch.from_numpy(s.train.content[rows]).long())
        t = tick("generator losses (rec, adv, per, cls)", t)
        cycle = config.w_cyc and i % config.cyc_every == 0
        if cycle:
            rot_c, vel_c, _ = G(torch.cat([ch[B:], x[..., L.contacts]], -1), tgt, ct, st)
            loss = loss + config.w_cyc * config.cyc_every * losses.reconstruction_loss(rot_c, G.raw_rotations(x), G.motion_channels(rot_c, vel_c), real, L)
            t = tick("cycle pass + loss", t)
        opt_g.zero_grad()
        loss.backward()
        opt_g.step()
        t = tick("generator backward + Adam, with the cycle" if cycle and config.cyc_every > 1 else "generator backward + Adam", t)
        real = real[..., L.positions.start :]
        loss_d = losses.critic(D(real, st, ct), D(ch[B:, :, L.positions.start :].detach(), tgt, ct))
        opt_d.zero_grad()
        loss_d.backward()
        opt_d.step()
        t = tick("critic step", t)
        losses.r1_penalty(D, real, st, ct).backward()
        tick(R1, t)

    for i in range(args.steps + 3):
        for name, config in recipes.items():
            step(name, config, i)
    steps = len(s.train.starts) // B
    print(f"batch {B}, {args.threads} threads, median of {args.steps} steps, recipes alternating step by step")
    total, report = {}, {"batch": B, "threads": args.threads, "steps": args.steps, "steps_per_epoch": steps}
    for name, times in parts.items():
        med = {k: float(np.median(v[3:] or v)) * 1000 for k, v in times.items()}
        # parts on every k-th step only count 1/k: R1 (every 4th), a lazy cycle pass and its backward
        every = {R1: 4, "cycle pass + loss": recipes[name].cyc_every, "generator backward + Adam, with the cycle": recipes[name].cyc_every}
        lazy = recipes[name].cyc_every > 1
        total[name] = sum(v / every.get(k, 1) for k, v in med.items())
        if lazy:  # a step with the cycle replaces a plain backward
            total[name] -= med["generator backward + Adam"] / recipes[name].cyc_every
        report[name] = {"config": getattr(args, name), "parts_ms": {k: round(v, 2) for k, v in med.items()}, "step_ms": round(total[name], 2)}
        print(f"{name}: {getattr(args, name)}")
        for k, v in med.items():
            print(f"  {k:38s} {v:7.2f} ms")
        print(f"  {'step (R1 amortised)':38s} {total[name]:7.2f} ms -> {steps} steps/epoch, {steps * total[name] / 1000:.1f} s/epoch")
    print(f"after / before step time: {total['after'] / total['before']:.3f} ({total['before'] / total['after']:.2f}x the steps per minute)")
    if args.json:
        report["speedup"] = round(total["before"] / total["after"], 3)
        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
