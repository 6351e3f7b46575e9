"""The repair model at work: ε-prediction tuning loss, and SDEdit + DDIM repair of a render.

Images are float tensors [B, 3, H, W] in [0, 1] with H, W multiples of 64 (see ``frame.Frame``). The
ControlNet (tile) is conditioned on the degraded render itself, the text on the Dreambooth-style prompt.
On CUDA the forward/backward runs under autocast in ``autocast_dtype`` (fp16/bf16); on CPU in float32.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from go_core.diffusion.models import RepairModels

DEFAULT_PROMPT = "a photo of xxy5syt00"


@dataclass
class RepairResult:
    images: torch.Tensor  # [B, 3, H, W] in [0, 1]
    timestep: int  # the SDEdit noise level t (in training timesteps, 0..T-1)
    steps: int  # DDIM steps run (⌊num_inference_steps · t / T⌋, at least 1)


class RepairDiffusion:
    """Wraps RepairModels with the prompt, device and precision used by the lora and repair steps."""

    def __init__(
        self,
        models: RepairModels,
        prompt: str = DEFAULT_PROMPT,
        device: str = "cpu",
        autocast_dtype: torch.dtype | None = None,
        guidance_scale: float = 1.0,
        conditioning_scale: float = 1.0,
    ) -> None:
        from diffusers import DDIMScheduler

        self.models = models
        self.prompt = prompt
        self.device = torch.device(device)
        self.autocast_dtype = autocast_dtype if self.device.type == "cuda" else None
        self.guidance_scale = guidance_scale
        self.conditioning_scale = conditioning_scale
        self.scheduler = DDIMScheduler.from_config(models.scheduler.config)  # own copy: set_timesteps mutates
        self.num_train_timesteps = int(self.scheduler.config.num_train_timesteps)
        self.alphas_cumprod = self.scheduler.alphas_cumprod.to(torch.float64)
        self.vae_scale = float(getattr(models.vae.config, "scaling_factor", 0.18215))

    # Precision ---------------------------------------------------------------------------------------------
    def autocast(self):
        if self.autocast_dtype is None:
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=self.autocast_dtype)

    # Pieces -----------------------------------------------------------------------------------------------
    def text_embeddings(self, prompt: str | None = None, batch: int = 1) -> torch.Tensor:
        tok = self.models.tokenizer
        ids = tok(
            prompt if prompt is not None else self.prompt,
            padding="max_length",
            max_length=tok.model_max_length,
            truncation=True,
            return_tensors="pt",
        ).input_ids
        with self.autocast():
            emb = self.models.text_encoder(ids.to(self.device))[0]
        return emb.expand(batch, -1, -1)

    def encode(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        vae = self.models.vae
        x = (images.to(self.device) * 2.0 - 1.0).to(next(vae.parameters()).dtype)
        with self.autocast():
            dist = vae.encode(x).latent_dist
        return dist.sample(generator=generator).float() * self.vae_scale

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        vae = self.models.vae
        with self.autocast():
            x = vae.decode((latents / self.vae_scale).to(next(vae.parameters()).dtype)).sample
        return ((x.float() + 1.0) / 2.0).clamp(0.0, 1.0)

    def predict_noise(
        self, noisy: torch.Tensor, t: torch.Tensor, cond: torch.Tensor, text: torch.Tensor
    ) -> torch.Tensor:
        """ε̂(z_t, t | prompt, ControlNet(cond))."""
        m = self.models
        dtype = next(m.unet.parameters()).dtype
        with self.autocast():
            down, mid = m.controlnet(
                noisy.to(dtype),
                t,
                encoder_hidden_states=text.to(dtype),
                controlnet_cond=cond.to(self.device, dtype),
                conditioning_scale=self.conditioning_scale,
                return_dict=False,
            )
            eps = m.unet(
                noisy.to(dtype),
                t,
                encoder_hidden_states=text.to(dtype),
                down_block_additional_residuals=down,
                mid_block_additional_residual=mid,
            ).sample
        return eps.float()

    # Tuning ----------------------------------------------------------------------------------------------
    def tuning_loss(
        self, degraded: torch.Tensor, clean: torch.Tensor, generator: torch.Generator
    ) -> torch.Tensor:
        """ε-prediction MSE: noise the clean latent, predict the noise with the ControlNet on the degraded."""
        b = clean.shape[0]
        with torch.no_grad():
            z0 = self.encode(clean, generator)
        noise = torch.randn(z0.shape, generator=generator, dtype=z0.dtype, device="cpu").to(z0.device)
        t = torch.randint(0, self.num_train_timesteps, (b,), generator=generator, device="cpu").to(
            self.device
        )
        zt = self.scheduler.add_noise(z0, noise, t)
        eps = self.predict_noise(zt, t, degraded, self.text_embeddings(batch=b))
        return F.mse_loss(eps, noise)

    def sds_loss(
        self, image: torch.Tensor, t_frac: float, generator: torch.Generator
    ) -> tuple[torch.Tensor, int]:
        """Score distillation (DreamFusion) through the VAE encoder: a loss whose gradient w.r.t. the latent
        is w(t)·(ε̂ − ε), with w(t) = 1 − ᾱ_t and the ControlNet conditioned on the (detached) image."""
        t = max(1, min(self.num_train_timesteps - 1, int(round(t_frac * self.num_train_timesteps))))
        vae = self.models.vae
        with self.autocast():
            z0 = vae.encode((image * 2.0 - 1.0).to(next(vae.parameters()).dtype)).latent_dist.mean
        z0 = z0.float() * self.vae_scale
        noise = torch.randn(z0.shape, generator=generator, dtype=z0.dtype, device="cpu").to(z0.device)
        tt = torch.full((z0.shape[0],), t, dtype=torch.long, device=self.device)
        with torch.no_grad():
            zt = self.scheduler.add_noise(z0.detach(), noise, tt)
            eps = self.predict_noise(zt, tt, image.detach(), self.text_embeddings(batch=z0.shape[0]))
        w = float(1.0 - self.alphas_cumprod[t])
        grad = torch.nan_to_num(w * (eps - noise))
        target = (z0 - grad).detach()
        return 0.5 * F.mse_loss(z0, target, reduction="sum") / z0.shape[0], t

    # Repair ----------------------------------------------------------------------------------------------
    def steps_for(self, t_frac: float, num_inference_steps: int) -> int:
        """⌊num_inference_steps · t/T⌋ DDIM steps, at least one."""
        return max(1, min(num_inference_steps, math.floor(num_inference_steps * t_frac)))

    @staticmethod
    def square_side(settings) -> int:
        """The side of the square views the repair loop gives ``restore``: ``sd15_resolution``."""
        return int(settings.sd15_resolution)

    @staticmethod
    def lpips_weight(settings) -> float:
        """The repair loss's LPIPS weight with this model: ``sd15_lpips``."""
        return float(settings.sd15_lpips)

    def restore(self, square: torch.Tensor, rng, generator, settings) -> tuple[torch.Tensor, int, float]:
        """One repaired view for the repair loop: (images, label, w): SDEdit at t/T drawn from
        ``settings.sd15_t_range`` (label = the timestep) with DreamFusion's weight w(t)."""
        from go_core.repair.weights import dreamfusion_weight

        t_frac = float(rng.uniform(*settings.sd15_t_range))
        res = self.repair(square, t_frac, generator, settings.sd15_num_inference_steps, settings.sd15_eta)
        return res.images, res.timestep, dreamfusion_weight(self.alphas_cumprod, res.timestep)

    @torch.no_grad()
    def repair(
        self,
        render: torch.Tensor,
        t_frac: float,
        generator: torch.Generator,
        num_inference_steps: int,
        eta: float,
    ) -> RepairResult:
        """SDEdit: encode the render, noise it to level t ≈ t_frac·T, denoise with DDIM (ControlNet on the
        render) for ⌊50·t/T⌋ steps and decode. ``eta``: DDIM stochasticity (1.0 as in the authors' code)."""
        k = self.steps_for(t_frac, num_inference_steps)
        self.scheduler.set_timesteps(num_inference_steps)
        timesteps = self.scheduler.timesteps[-k:]
        b = render.shape[0]
        z0 = self.encode(render, generator)
        noise = torch.randn(z0.shape, generator=generator, dtype=z0.dtype, device="cpu").to(z0.device)
        z = self.scheduler.add_noise(z0, noise, timesteps[:1].repeat(b).to(self.device))
        text = self.text_embeddings(batch=b)
        cfg = self.guidance_scale > 1.0
        if cfg:
            text = torch.cat([self.text_embeddings("", batch=b), text])
        for t in timesteps:
            tt = t.to(self.device)
            if cfg:
                e_u, e_c = self.predict_noise(torch.cat([z, z]), tt, torch.cat([render, render]), text).chunk(
                    2
                )
                eps = e_u + self.guidance_scale * (e_c - e_u)
            else:
                eps = self.predict_noise(z, tt, render, text)
            noise_t = None
            if eta > 0:
                noise_t = torch.randn(z.shape, generator=generator, dtype=z.dtype, device="cpu").to(z.device)
            z = self.scheduler.step(eps, t, z, eta=eta, variance_noise=noise_t).prev_sample
        return RepairResult(self.decode(z), int(timesteps[0]), k)
