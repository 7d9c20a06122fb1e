"""`cgan`: the DCGAN of helioflow.models.dcgan conditioned on the sun position, usable as a
predictor (controllable: a sun position in, one focal-spot image out).

Conditioning, in both networks, on c = sun_features(azimuth, elevation), the (N, 3) unit vector
towards the sun (continuous, no wrap-around):

* generator: input = concat(z, embed(c)), embed = Linear(3, cond_embed) + LeakyReLU(0.2); then
  the same transposed-convolution stack as the DCGAN.
* discriminator: c broadcast to three constant (N, 3, H, W) maps concatenated to the image
  channels (input 4 x H x W); then the same convolution stack as the DCGAN.

Generator loss = non-saturating adversarial loss + `l1_weight` * mean |G(z, c) - x| against the
real image x of the same sun position (pix2pix, Isola et al. 2017, weight 100). The L1 term ties
each condition to its measured spot, which is what makes the cGAN a predictor rather than a
sampler; the adversarial term keeps the spot sharp. `predict` uses the fixed latent z = 0 (the
mean of the training noise N(0, 1)), so the same sun position always gives the same image.

Measured on the 2-core development CPU (torch 2.13, batch 32, 64x64, default config): about
0.06-0.07 s per training step with 2 threads on an idle machine, 0.075-0.085 s with 1 thread
(the DCGAN: about 10 % less; see helioflow.models.dcgan on thread oversubscription).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from helioflow.checks import check_ranges
from helioflow.models.base import SpotModel, sun_features
from helioflow.models.dcgan import Discriminator, GanConfig, Generator, adam_pair, adversarial_step

CONDITION_DIM = 3  # sun_features: unit vector towards the sun


@dataclass(frozen=True)
class CganConfig(GanConfig):
    """Settings of the conditional GAN: those of GanConfig (latent, features, max_mult, lr,
    beta1, beta2), except a higher default learning rate, and

    Attributes:
        lr: Adam learning rate of both networks; 1e-3 rather than DCGAN's 2e-4 because the L1
            term makes the generator mostly a regressor (on sanity_check, batch 32, interpolation
            PSNR after 150 steps: 34 dB at 1e-3, 16 dB at 2e-4; after 300 steps at 1e-3: 35-40 dB,
            varying with the initialisation and the thread count).
        cond_embed: width of the generator's embedding of the sun direction.
        l1_weight: weight of the L1 reconstruction term in the generator loss (0: a pure cGAN).
    """

    lr: float = 1e-3
    cond_embed: int = 16
    l1_weight: float = 100.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_ranges(self, at_least_one=("cond_embed",), non_negative=("l1_weight",))


class ConditionalGAN(SpotModel):
    """Sun-position-conditioned GAN: `netG` ((z, c) -> image) and `netD` ((image, c) -> logit)."""

    name = "cgan"
    controllable = True

    def __init__(self, config: CganConfig, image_shape: tuple[int, int]):
        super().__init__()
        self.config = config
        self.image_shape = (image_shape[0], image_shape[1])
        self.netG = Generator(self.image_shape, config.latent, config.features, config.max_mult,
                              cond_dim=CONDITION_DIM, cond_embed=config.cond_embed)
        self.netD = Discriminator(self.image_shape, config.features, config.max_mult, cond_channels=CONDITION_DIM)

    def configure_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """Adam for the generator and for the discriminator (`adam_pair`)."""
        return adam_pair(self.netG, self.netD, self.config)

    def training_step(self, batch: dict[str, Tensor], optimizers: dict, generator: torch.Generator) -> dict[str, float]:
        """One discriminator and one generator step on the batch, conditioned on its sun positions."""
        real = batch["images"]
        condition = sun_features(batch["azimuth_deg"], batch["elevation_deg"])
        z = torch.randn(len(real), self.config.latent, generator=generator).to(self.device)
        return adversarial_step(self.netG, self.netD, optimizers, real, z, condition, self.config.l1_weight,
                                self.config.real_label)

    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor, generator: torch.Generator) -> Tensor:
        """(N, H, W) in [0, 1] from the fixed latent z = 0: deterministic, `generator` is unused.

        Differentiable with respect to the positions when called with gradients enabled.
        """
        condition = sun_features(azimuth_deg.to(self.device), elevation_deg.to(self.device))
        z = condition.new_zeros(len(condition), self.config.latent)
        return self.netG(z, condition)
