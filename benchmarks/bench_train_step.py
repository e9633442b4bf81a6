"""Where a training step's time goes (the shipped recipe: batch 32, paper-sized networks).

    python benchmarks/bench_train_step.py [--steps 40] [--batch 32] [--threads 2]

Times each part of a step on real Bandai-Namco-2 windows, median over steps, and the epoch
time it implies.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from styleerd.model.discriminator import Discriminator
from styleerd.train import losses
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import make_generator, setup
from styleerd.model.classifiers import WindowClassifier


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    config = TrainConfig(batch_size=args.batch)
    s = setup(config, None, progress=False)
    G = make_generator(config, s)
    J, L, B = G.config.n_joints, G.layout, args.batch
    D = Discriminator(6 * J, len(s.data.styles), len(s.data.contents), config.window)
    C = WindowClassifier(10 * J, len(s.data.contents), instance_norm=True).requires_grad_(False)
    opt_g, opt_d = torch.optim.Adam(G.parameters()), torch.optim.Adam(D.parameters())
    rng = np.random.default_rng(0)
    parts: dict[str, list[float]] = {}

    def tick(name: str, t0: float) -> float:
        t = time.perf_counter()
        parts.setdefault(name, []).append(t - t0)
        return t

    for _ in range(args.steps + 3):
        rows = rng.choice(len(s.train.starts), B)
        t = time.perf_counter()
        x = s.data.gather(s.train.starts[rows])
        st, ct = s.data.onehot_style(s.train.style[rows]), s.data.onehot_content(s.train.content[rows])
        tgt = s.data.onehot_style(rng.integers(0, len(s.data.styles), B))
        t = tick("batch gather", t)
        rot, vel, _ = G(torch.cat([x, x]), torch.cat([st, st]), torch.cat([ct, ct]), torch.cat([st, tgt]))
        t = tick("generator forward (2B)", t)
        ch = G.motion_channels(rot, vel)
        t = tick("forward kinematics + channels", t)
        loss = losses.reconstruction_loss(rot[:B], G.raw_rotations(x), ch[:B], x[..., : 10 * J], L)
        loss = loss + losses.generator_adversarial(D(ch[B:, :, L.positions.start :], tgt, ct)) + 0.1 * losses.perceptual(C, x[..., : 10 * J], ch[B:])
        t = tick("generator losses (rec, adv, per)", t)
        opt_g.zero_grad()
        loss.backward()
        opt_g.step()
        t = tick("generator backward + Adam", t)
        real = x[..., L.positions.start : 10 * J]
        loss_d = losses.critic(D(real, st, ct), D(ch[B:, :, L.positions.start :].detach(), tgt, ct))
        opt_d.zero_grad()
        loss_d.backward()
        opt_d.step()
        t = tick("critic step", t)
        r1 = losses.r1_penalty(D, real, st, ct)
        r1.backward()
        tick("R1 penalty (every 4th step)", t)
    med = {k: float(np.median(v[3:])) * 1000 for k, v in parts.items()}
    step = sum(v for k, v in med.items() if not k.startswith("R1")) + med["R1 penalty (every 4th step)"] / 4
    steps = len(s.train.starts) // B
    print(f"batch {B}, {args.threads} threads, median of {args.steps} steps")
    for k, v in med.items():
        print(f"  {k:34s} {v:7.2f} ms")
    print(f"  {'step (R1 amortised)':34s} {step:7.2f} ms -> {steps} steps/epoch, {steps * step / 1000:.1f} s/epoch")


if __name__ == "__main__":
    main()
