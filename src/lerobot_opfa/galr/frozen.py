"""The frozen GaLR a policy or a dataset cache refers to: loading it once, and a fingerprint of its weights
so cached latents are only trusted when they came from the same model."""

from __future__ import annotations

import copy
import hashlib
from functools import cache

import torch

from lerobot_opfa.galr import checkpoints
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.registry import builtin_hands, load_spec


def load_galr(ref: str) -> Galr:
    """A GaLR checkpoint (packaged name, local folder or Hub repo id), frozen, in eval mode: the caller's
    own copy (a pipeline moves its GaLR to its device; another's stays where it is), read once per
    process."""
    return copy.deepcopy(_read_galr(ref))


@cache
def _read_galr(ref: str) -> Galr:
    galr = checkpoints.load(ref)
    galr.requires_grad_(False)
    return galr


def galr_fingerprint(galr: Galr) -> str:
    """sha256 over the weights (names, shapes and bytes): equal iff the model computes the same latents."""
    digest = hashlib.sha256()
    for name, tensor in sorted(galr.state_dict().items()):
        digest.update(name.encode())
        digest.update(str(tuple(tensor.shape)).encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def known_hand_refs(galr: Galr | None) -> list[str]:
    """Hands a dataset may name, as `load_hand` takes them: the built-ins plus the GaLR's own (spec paths).
    Wider than the GaLR's registry on purpose, so a hand it lacks is recognised and reported as such."""
    builtins = list(builtin_hands())
    extra = [h["spec"] for h in galr.config.hands if h["name"] not in builtins] if galr is not None else []
    return builtins + extra


def galr_hand_refs(galr: Galr) -> list[str]:
    """What `load_hand` takes for each hand of the GaLR's registry: built-in names, else spec paths."""
    builtins = builtin_hands()
    return [h["name"] if h["name"] in builtins else h["spec"] for h in galr.config.hands]


def relocate_hand(galr: Galr, name: str, spec: str) -> None:
    """Points the registry entry of hand `name` at `spec`, the copy of its files a policy checkpoint carries
    (`hands.bundle`): its path and hash differ from the original's (the spec names the model by its place
    in the copy), the hand does not."""
    record = next(h for h in galr.config.hands if h["name"] == name)
    record["spec"], record["sha256"] = spec, load_spec(spec).sha256


@torch.no_grad()
def encode_joints(galr: Galr, hand: str, q: torch.Tensor, batch_size: int = 1024) -> torch.Tensor:
    """(..., dof) joints of `hand` -> (..., latent_dim), in chunks so big caches fit in memory."""
    flat = q.reshape(-1, q.shape[-1]).to(galr.device, torch.float32)
    z = [galr.encode_joints(hand, flat[i : i + batch_size]) for i in range(0, len(flat), batch_size)]
    out = torch.cat(z) if z else flat.new_zeros(0, galr.config.latent_dim)
    return out.reshape(*q.shape[:-1], -1)


@torch.no_grad()
def encode_universal(
    galr: Galr, hands: list[str], universal: torch.Tensor, ids: torch.Tensor
) -> torch.Tensor:
    """(B, ..., U) universal joints of rows whose hand is `hands[ids]` (ids (B,)) -> (B, ..., latent_dim)."""
    z = universal.new_zeros(*universal.shape[:-1], galr.config.latent_dim)
    for index in ids.unique().tolist():
        rows = ids == index
        q = galr.hand(hands[index])[0].from_universal(universal[rows])
        z[rows] = encode_joints(galr, hands[index], q)
    return z
