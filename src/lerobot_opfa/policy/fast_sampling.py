"""Sampling on a CPU at batch 1, paid on every chunk of a rollout: the weights of `ConditionalUnet1d` run
time-major (each convolution one matmul on unfolded windows), the FiLM inputs of all DDIM steps in one
batch, the steps through one frozen TorchScript graph, and, on a CPU, float16 copies of the convolution
weights (`benchmarks/bench_policy.py` measures what each saves). `OpfaConfig.cpu_fast_sampling=False`
switches it off; tests pin it against the plain U-Net."""

from __future__ import annotations

import warnings
from contextlib import contextmanager, nullcontext

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from lerobot_opfa.policy.diffusion import ConditionalUnet1d, ConvBlock, FiLMResidualBlock


def linear_weights(layer: nn.Conv1d | nn.ConvTranspose1d) -> tuple[Tensor, Tensor | None]:
    """A convolution as a linear layer: on the unfolded windows (conv) or on the input, whose per-tap
    products are then summed into overlapping windows (transposed conv)."""
    if isinstance(layer, nn.ConvTranspose1d):
        return layer.weight.flatten(1).T, None
    return layer.weight.flatten(1), layer.bias


def linear(x: Tensor, layer: nn.Conv1d | nn.ConvTranspose1d) -> Tensor:
    """`layer` as a linear layer on x, through its float16 weights while `float16_weights` has packed them."""
    packed = getattr(layer, "float16_packed", None)
    if packed is not None:
        return torch.ops.quantized.linear_dynamic_fp16(x, packed)
    return F.linear(x, *linear_weights(layer))


@contextmanager
def float16_weights(layers: list[nn.Conv1d | nn.ConvTranspose1d]):
    """Within: `conv` and `conv_transpose` multiply by float16 copies of the layers' weights and accumulate in
    float32 (fbgemm, CPU only). At batch 1 a U-Net pass on a CPU is bound by streaming its weights from
    memory, so half the bytes is a faster pass; products differ from float32 by about 2e-4 relative."""
    for layer in layers:
        weight, bias = linear_weights(layer)
        bias = None if bias is None else bias.detach()
        layer.float16_packed = torch.ops.quantized.linear_prepack_fp16(weight.detach().contiguous(), bias)
    try:
        yield
    finally:
        for layer in layers:
            del layer.float16_packed


def conv(x: Tensor, layer: nn.Conv1d) -> Tensor:
    """`layer` on time-major features (B, T, C): the unfolded windows times the flattened weights, one
    matmul. Same maths as `F.conv1d` on (B, C, T), several times faster on a CPU at batch 1, where
    `F.conv1d` takes an im2col path with the output laid out (C_out, T), a GEMM shape MKL runs poorly."""
    (k,), (stride,), (pad,) = layer.kernel_size, layer.stride, layer.padding
    if k > 1 or stride > 1:
        x = F.pad(x, (0, 0, pad, pad)).unfold(1, k, stride).flatten(2)
    return linear(x, layer)


def conv_transpose(x: Tensor, layer: nn.ConvTranspose1d) -> Tensor:
    """`layer` on time-major features (B, T, C): one matmul, then overlapping windows summed (col2im)."""
    (k,), (stride,), (pad,) = layer.kernel_size, layer.stride, layer.padding
    b, t, _ = x.shape
    length = (t - 1) * stride - 2 * pad + k
    cols = linear(x, layer).transpose(1, 2)
    out = F.fold(cols, (1, length), (1, k), padding=(0, pad), stride=(1, stride))
    return out.view(b, -1, length).transpose(1, 2) + layer.bias


def conv_block(x: Tensor, block: ConvBlock) -> Tensor:
    """`block` on time-major features (B, T, C)."""
    layer, norm, _ = block
    h = conv(x, layer).mT.unsqueeze(2)  # (B, C, 1, T), channels-last in memory: no copy for the norm
    return F.mish(F.group_norm(h, norm.num_groups, norm.weight, norm.bias, norm.eps)).squeeze(2).mT


def film_block(x: Tensor, film: Tensor, block: FiLMResidualBlock) -> Tensor:
    """`block` on time-major x (B, T, C_in) with its FiLM output film (B, 1, C_out [* 2])."""
    h = conv_block(x, block.first)
    c = block.c_out
    h = torch.addcmul(film[..., c:], h, film[..., :c]) if block.use_scale else h + film
    skip = x if isinstance(block.skip, nn.Identity) else conv(x, block.skip)
    return conv_block(h, block.second) + skip


def films(unet: ConditionalUnet1d, t: Tensor, cond: Tensor) -> list[Tensor]:
    """Each block's FiLM output (B, 1, F) for steps t (B,) and observation features cond (B, C): all that
    does not depend on the noisy sample. The Mish every block's `film` starts with is applied once here."""
    cond = F.mish(torch.cat([unet.step_embedding(t), cond], dim=-1))
    return [block.film[1](cond).unsqueeze(1) for block in unet.film_blocks]


def denoise(unet: ConditionalUnet1d, x: Tensor, step_films: list[Tensor], head: Tensor | None) -> Tensor:
    """`unet(x, t, cond, head)` time-major, from the FiLM outputs of `films`: x (B, T, A) -> (B, T, A)."""
    step_films = iter(step_films)
    h, skips = x, []
    for first, second, down in unet.down:
        h = film_block(film_block(h, next(step_films), first), next(step_films), second)
        skips.append(h)
        h = h if isinstance(down, nn.Identity) else conv(h, down)
    for block in unet.mid:
        h = film_block(h, next(step_films), block)
    for first, second, up in unet.up:
        h = film_block(torch.cat([h, skips.pop()], dim=-1), next(step_films), first)
        h = conv_transpose(film_block(h, next(step_films), second), up)
    out = conv(conv_block(h, unet.final), unet.heads)
    if unet.n_heads > 1:
        out = out.view(*out.shape[:2], unet.n_heads, unet.action_dim)  # each entry's own head:
        index = head.view(len(out), 1, 1, unet.action_dim).expand(-1, out.shape[1], 1, -1)
        out = out.gather(2, index).squeeze(2)
    return out


class FastSampler:
    """`denoiser(timesteps, cond, head)` for `Ddim.sample`, through frozen traces of `denoise` made at the
    first call per input shape, device and dtype. A chunk is ten U-Net passes of hundreds of small ops at
    batch 1; run as one graph they skip Python's per-op dispatch, a third of a pass's time on a CPU, and
    freezing (weights as constants) takes off another sixth. The traces are made again when the weights
    change: an optimiser step, `load_state_dict` or a move changes a parameter's storage or its version
    counter (torch counts every in-place write), and the traces are keyed by both. torch
    2.11 marks `torch.jit.trace` deprecated in favour of `torch.compile`, which here costs about 50 s per
    process and a C++ toolchain and ran no faster (3.9 vs 3.5 ms per pass), so the trace stays and its
    warnings are silenced."""

    def __init__(self, unet: ConditionalUnet1d, float16_weights: bool):
        self.unet = unet
        self.float16 = float16_weights and "fbgemm" in torch.backends.quantized.supported_engines
        self.traces: dict[tuple, torch.jit.ScriptModule] = {}
        self.weights: tuple = ()
        """(storage, version) of each U-Net parameter when the traces were made."""

    def denoiser(self, timesteps: list[int], cond: Tensor, head: Tensor | None = None):
        """`denoise(x, i)` at the i-th of `timesteps`; the FiLM inputs of all steps are computed up front,
        and the traces checked against the weights once for the chunk."""
        weights = tuple((p.data_ptr(), p._version) for p in self.unet.parameters())
        if weights != self.weights:
            self.traces, self.weights = {}, weights
        b, n = len(cond), len(timesteps)
        t = torch.tensor(timesteps, device=cond.device).repeat_interleave(b)
        all_films = films(self.unet, t, cond.repeat(n, 1))
        steps = list(zip(*(f.view(n, b, *f.shape[1:]).unbind() for f in all_films), strict=True))
        return lambda x, i: self._traced(x, steps[i], head)

    def _traced(self, x: Tensor, step_films: tuple[Tensor, ...], head: Tensor | None) -> Tensor:
        inputs = (x, step_films) if head is None else (x, step_films, head)
        key = (x.shape, x.device, x.dtype, head is None)
        if key not in self.traces:
            float16 = self.float16 and x.device.type == "cpu" and x.dtype == torch.float32
            layers = [m for m in self.unet.modules() if isinstance(m, (nn.Conv1d, nn.ConvTranspose1d))]
            with warnings.catch_warnings(), float16_weights(layers) if float16 else nullcontext():
                warnings.simplefilter("ignore", DeprecationWarning)
                warnings.simplefilter("ignore", torch.jit.TracerWarning)
                trace = torch.jit.trace(_Denoise(self.unet), inputs, check_trace=False)
                self.traces[key] = torch.jit.freeze(trace.eval())
        return self.traces[key](*inputs)


class _Denoise(nn.Module):
    """`denoise` as a module's forward, the form `torch.jit.trace` takes."""

    def __init__(self, unet: ConditionalUnet1d):
        super().__init__()
        self.unet = unet

    def forward(self, x: Tensor, step_films: tuple[Tensor, ...], head: Tensor | None = None) -> Tensor:
        return denoise(self.unet, x, list(step_films), head)
