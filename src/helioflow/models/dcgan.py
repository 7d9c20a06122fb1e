"""`gan`: an unconditioned DCGAN of focal-spot images (Pargmann et al., "Towards a Neural Network
Based Flux Density Prediction"), after pytorch/examples `dcgan`.

It learns the distribution of the training spots and ignores the sun position: `predict` returns
N independent samples. It is the baseline that shows what a generative model without control
gives; the conditioned variant (`cgan`, helioflow.models.cgan) reuses the building blocks here.

Architecture (4x4 kernels, stride 2, padding 1 throughout, so every layer halves or doubles the
spatial size; the stack is built from the image size, any power of two >= 16). With the defaults
(features f = 16, max_mult = 8) on 64x64 images the state sizes are::

    discriminator                          generator
    input      1 x 64 x 64                 z          latent x 1 x 1
    conv  ->   f x 32 x 32  LeakyReLU      convT ->  8f x 2 x 2    BN ReLU
    conv  ->  2f x 16 x 16  BN LeakyReLU   convT ->  8f x 4 x 4    BN ReLU
    conv  ->  4f x 8 x 8    BN LeakyReLU   convT ->  4f x 8 x 8    BN ReLU
    conv  ->  8f x 4 x 4    BN LeakyReLU   convT ->  2f x 16 x 16  BN ReLU
    conv  ->  8f x 2 x 2    BN LeakyReLU   convT ->   f x 32 x 32  BN ReLU
    conv  ->   1 x 1 x 1    (logit)        convT ->   1 x 64 x 64  sigmoid

Widths are f * min(2**i, max_mult) at the i-th halving; no batch norm on the discriminator's
first layer (as in DCGAN); LeakyReLU slope 0.2; weights N(0, 0.02), batch-norm scales N(1, 0.02).
The generator ends in a sigmoid because images are normalised by the dataset maximum
(background 0, values in [0, 1]); its last layer alone has a bias, initialised to -4 so that the
first samples are nearly black like the mostly-zero background instead of uniformly 0.5 (from
0.5 the background takes hundreds of steps to fall into the flat tail of the sigmoid).

Training: the non-saturating GAN loss with BCE on logits, one discriminator then one generator
Adam step per batch; the latent noise comes from the step's torch.Generator.

Measured on the 2-core development CPU (torch 2.13, batch 32, 64x64, default config): about
0.05 s per training step with 2 threads on an idle machine, 0.07-0.08 s with 1 thread; with
2 threads while another job uses the cores, 0.2-3 s (thread oversubscription), so run parallel
jobs with one torch thread each. The cGAN costs about 10 % more.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from helioflow.checks import check_ranges, check_types
from helioflow.errors import ConfigError
from helioflow.models.base import SpotModel

KERNEL, STRIDE, PADDING = 4, 2, 1
LEAKY_SLOPE = 0.2
OUTPUT_BIAS = -4.0  # initial bias before the generator's sigmoid: sigmoid(-4) = 0.018


@dataclass(frozen=True)
class GanConfig:
    """Settings of the DCGAN (the training loop's steps/batch size are separate).

    Attributes:
        latent: length of the generator's noise vector z ~ N(0, 1).
        features: base width f: channels after the discriminator's first layer (and before the
            generator's last); each further halving of the image doubles it up to f * max_mult.
        max_mult: cap on the width multiplier (DCGAN uses 8).
        lr: Adam learning rate of both networks (DCGAN: 2e-4).
        beta1: Adam beta1 (DCGAN: 0.5).
        beta2: Adam beta2.
        real_label: the discriminator's target for real images; below 1 it is one-sided label
            smoothing (Salimans et al. 2016), which keeps D from winning outright.
    """

    latent: int = 64
    features: int = 16
    max_mult: int = 8
    lr: float = 2e-4
    beta1: float = 0.5
    beta2: float = 0.999
    real_label: float = 1.0

    def __post_init__(self) -> None:
        check_types(self)
        check_ranges(self, at_least_one=("latent", "features", "max_mult"), positive=("lr",),
                     below_one=("beta1", "beta2"), fraction=("real_label",),
                     at_most={"latent": (4096, "the generator's input width"),
                              "features": (1024, "channels grow to features x max_mult: weights and memory"),
                              "max_mult": (64, "channels grow to features x max_mult: weights and memory")})


def halvings(image_shape: tuple[int, int]) -> int:
    """Number of stride-2 layers from a square power-of-two image (>= 16) down to 1x1."""
    h, w = (int(s) for s in image_shape)
    if h != w or h < 16 or h & (h - 1):
        raise ConfigError(f"the GANs need square images with a power-of-two side >= 16, got {h}x{w}")
    return h.bit_length() - 1


def widths(levels: int, features: int, max_mult: int) -> list[int]:
    """Channels at spatial sizes size/2, size/4, ..., 2 (levels - 1 entries)."""
    return [features * min(2**i, max_mult) for i in range(levels - 1)]


def weights_init(module: nn.Module) -> None:
    """DCGAN initialisation: conv weights N(0, 0.02); batch-norm scales N(1, 0.02), shifts 0."""
    if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
        nn.init.normal_(module.weight, 0.0, 0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
    elif isinstance(module, nn.BatchNorm2d):
        nn.init.normal_(module.weight, 1.0, 0.02)
        nn.init.zeros_(module.bias)


class Discriminator(nn.Module):
    """(N, 1, H, W) images [+ (N, C) condition] -> (N,) logits (real > 0).

    With `cond_channels` > 0 the condition vector is broadcast to constant (N, C, H, W) maps and
    concatenated to the image channels before the first convolution.
    """

    def __init__(self, image_shape: tuple[int, int], features: int, max_mult: int = 8, cond_channels: int = 0):
        super().__init__()
        levels = halvings(image_shape)
        chans = widths(levels, features, max_mult)
        self.cond_channels = cond_channels
        # first halving: (1 + C) x H x W -> f x H/2 x W/2, no batch norm
        layers: list[nn.Module] = [nn.Conv2d(1 + cond_channels, chans[0], KERNEL, STRIDE, PADDING, bias=False),
                                   nn.LeakyReLU(LEAKY_SLOPE, inplace=True)]
        # each further halving: c_in x s x s -> c_out x s/2 x s/2, down to 2 x 2
        for c_in, c_out in pairwise(chans):
            layers += [nn.Conv2d(c_in, c_out, KERNEL, STRIDE, PADDING, bias=False), nn.BatchNorm2d(c_out),
                       nn.LeakyReLU(LEAKY_SLOPE, inplace=True)]
        # last halving: c x 2 x 2 -> 1 x 1 x 1, the logit
        layers.append(nn.Conv2d(chans[-1], 1, KERNEL, STRIDE, PADDING, bias=False))
        self.main = nn.Sequential(*layers)
        self.apply(weights_init)

    def forward(self, images: Tensor, condition: Tensor | None = None) -> Tensor:
        """(N, 1, H, W) images [+ (N, C) condition] -> (N,) logits."""
        if self.cond_channels:
            n, _, h, w = images.shape
            assert condition is not None, "a conditioned discriminator needs the condition"
            images = torch.cat((images, condition[:, :, None, None].expand(n, self.cond_channels, h, w)), dim=1)
        return self.main(images).flatten()


class Generator(nn.Module):
    """(N, latent) noise [+ (N, cond_dim) condition] -> (N, H, W) images in [0, 1].

    With `cond_dim` > 0 the condition passes through a small embedding (Linear, LeakyReLU) of
    width `cond_embed` that is concatenated to z before the first transposed convolution.
    """

    def __init__(self, image_shape: tuple[int, int], latent: int, features: int, max_mult: int = 8,
                 cond_dim: int = 0, cond_embed: int = 0):
        super().__init__()
        levels = halvings(image_shape)
        chans = widths(levels, features, max_mult)[::-1]  # widths at 2, 4, ..., size/2
        self.latent = latent
        self.embed = (nn.Sequential(nn.Linear(cond_dim, cond_embed), nn.LeakyReLU(LEAKY_SLOPE))
                      if cond_dim else None)
        # first doubling: (latent + embed) x 1 x 1 -> c x 2 x 2
        layers: list[nn.Module] = [nn.ConvTranspose2d(latent + (cond_embed if cond_dim else 0), chans[0], KERNEL,
                                                      STRIDE, PADDING, bias=False),
                                   nn.BatchNorm2d(chans[0]), nn.ReLU(inplace=True)]
        # each further doubling: c_in x s x s -> c_out x 2s x 2s, up to size/2
        for c_in, c_out in pairwise(chans):
            layers += [nn.ConvTranspose2d(c_in, c_out, KERNEL, STRIDE, PADDING, bias=False), nn.BatchNorm2d(c_out),
                       nn.ReLU(inplace=True)]
        # last doubling: f x size/2 -> 1 x size x size, squashed to [0, 1]
        out = nn.ConvTranspose2d(chans[-1], 1, KERNEL, STRIDE, PADDING, bias=True)
        layers += [out, nn.Sigmoid()]
        self.main = nn.Sequential(*layers)
        self.apply(weights_init)
        assert out.bias is not None  # bias=True
        nn.init.constant_(out.bias, OUTPUT_BIAS)  # start near the black background, not at 0.5

    def forward(self, z: Tensor, condition: Tensor | None = None) -> Tensor:
        """(N, latent) noise [+ (N, C) condition] -> (N, H, W) images."""
        if self.embed is not None:
            z = torch.cat((z, self.embed(condition)), dim=1)
        return self.main(z[:, :, None, None])[:, 0]


def adam_pair(generator: nn.Module, discriminator: nn.Module, config: GanConfig) -> dict[str, torch.optim.Optimizer]:
    """{'generator': Adam, 'discriminator': Adam} with the config's lr and betas."""
    betas = (config.beta1, config.beta2)
    return {"generator": torch.optim.Adam(generator.parameters(), lr=config.lr, betas=betas),
            "discriminator": torch.optim.Adam(discriminator.parameters(), lr=config.lr, betas=betas)}


def adversarial_step(generator: Generator, discriminator: Discriminator, optimizers: dict, real: Tensor, z: Tensor,
                     condition: Tensor | None = None, l1_weight: float = 0.0,
                     real_label: float = 1.0) -> dict[str, float]:
    """One discriminator then one generator step with the non-saturating GAN loss.

    D maximises log D(x) + log(1 - D(G(z))) with the real target `real_label` (< 1: one-sided
    label smoothing); G maximises log D(G(z)) (BCE with logits, target 1), plus
    `l1_weight` * mean |G(z, c) - x| when l1_weight > 0 (pix2pix; x is the real image of the
    same condition).

    Args:
        real: (B, H, W) real images; z: (B, latent) noise; condition: (B, C) or None.

    Returns:
        {'loss_d', 'loss_g'} (and 'loss_l1' when l1_weight > 0): loss_d is the sum of the real
        and fake terms, loss_g the adversarial term only.
    """
    opt_g, opt_d = optimizers["generator"], optimizers["discriminator"]
    real = real[:, None]
    fake = generator(z, condition)[:, None]

    # (1) discriminator: real -> real_label, fake -> 0 (fake detached: no gradient into G)
    opt_d.zero_grad(set_to_none=True)
    logit_real = discriminator(real, condition)
    logit_fake = discriminator(fake.detach(), condition)
    loss_d = (F.binary_cross_entropy_with_logits(logit_real, torch.full_like(logit_real, real_label))
              + F.binary_cross_entropy_with_logits(logit_fake, torch.zeros_like(logit_fake)))
    loss_d.backward()
    opt_d.step()

    # (2) generator: fool the updated discriminator (non-saturating: fake -> 1)
    opt_g.zero_grad(set_to_none=True)
    logit = discriminator(fake, condition)
    loss_g = F.binary_cross_entropy_with_logits(logit, torch.ones_like(logit))
    losses = {"loss_d": loss_d.item(), "loss_g": loss_g.item()}
    total = loss_g
    if l1_weight > 0:
        loss_l1 = F.l1_loss(fake, real)
        total = total + l1_weight * loss_l1
        losses["loss_l1"] = loss_l1.item()
    total.backward()
    opt_g.step()
    return losses


class DCGAN(SpotModel):
    """Unconditioned DCGAN: `netG` (noise -> image) and `netD` (image -> logit)."""

    name = "gan"
    controllable = False

    def __init__(self, config: GanConfig, image_shape: tuple[int, int]):
        super().__init__()
        self.config = config
        self.image_shape = (image_shape[0], image_shape[1])
        self.netG = Generator(self.image_shape, config.latent, config.features, config.max_mult)
        self.netD = Discriminator(self.image_shape, config.features, config.max_mult)

    def configure_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """Adam for the generator and for the discriminator (`adam_pair`)."""
        return adam_pair(self.netG, self.netD, self.config)

    def training_step(self, batch: dict[str, Tensor], optimizers: dict, generator: torch.Generator) -> dict[str, float]:
        """One discriminator and one generator step on the batch (`adversarial_step`)."""
        real = batch["images"]
        z = torch.randn(len(real), self.config.latent, generator=generator).to(self.device)
        return adversarial_step(self.netG, self.netD, optimizers, real, z, real_label=self.config.real_label)

    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor, generator: torch.Generator) -> Tensor:
        """N samples (N, H, W) in [0, 1], N = len(azimuth_deg); the positions are ignored."""
        z = torch.randn(len(azimuth_deg), self.config.latent, generator=generator).to(self.device)
        return self.netG(z)
