"""The losses of the paper (see ../shared/PAPER.md), on normalised motion channels."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from styleerd.data.features import FeatureLayout
from styleerd.model import torch_quat
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.discriminator import Discriminator


def reconstruction_loss(
    rot: torch.Tensor,
    rot_target: torch.Tensor,
    channels: torch.Tensor,
    channels_target: torch.Tensor,
    layout: FeatureLayout,
) -> torch.Tensor:
    """L_quat + 0.5 ||p - p''||^2 + ||v - v''||^2 (positions and velocities normalised)."""
    return (
        torch_quat.angle_loss(rot, rot_target)
        + 0.5 * F.mse_loss(channels[..., layout.positions], channels_target[..., layout.positions])
        + F.mse_loss(channels[..., layout.velocities], channels_target[..., layout.velocities])
    )


def generator_adversarial(d_fake: torch.Tensor) -> torch.Tensor:
    return d_fake.pow(2).mean()


def critic(d_real: torch.Tensor, d_fake: torch.Tensor) -> torch.Tensor:
    return (d_real - 1).pow(2).mean() + (d_fake + 1).pow(2).mean()


def r1_penalty(disc: Discriminator, real: torch.Tensor, style: torch.Tensor, content: torch.Tensor) -> torch.Tensor:
    """Mean over the batch of ||grad_x D(x)||^2 on real windows."""
    real = real.detach().requires_grad_(True)
    (grad,) = torch.autograd.grad(disc(real, style, content).sum(), real, create_graph=True)
    return grad.pow(2).sum(dim=(1, 2)).mean()


def perceptual(classifier: WindowClassifier, source: torch.Tensor, output_maps: list[torch.Tensor]) -> torch.Tensor:
    """MSE between the content classifier's feature maps of the input and of the output
    (``output_maps``: ``classifier.feature_maps(output)``, which content_classification shares)."""
    with torch.no_grad():
        target = classifier.feature_maps(source)
    return sum(F.mse_loss(o, t) for o, t in zip(output_maps, target))


def content_classification(
    classifier: WindowClassifier, output_maps: list[torch.Tensor], content: torch.Tensor
) -> torch.Tensor:
    """Cross-entropy of the (frozen) content classifier on the output (its feature maps)
    against the input's content label ``[B]``: the transfer must still read as the same action."""
    return F.cross_entropy(classifier.logits(output_maps[-1]), content)
