"""Ending a multi-process run (torchrun, accelerate on gloo) without a rank hanging after its checkpoint.

Seen in `make test` (torch 2.11, Python 3.13), from the stack of the hung rank: when LeRobot's training
function returns, its DDP-wrapped policy is freed; DDP's reducer holds the last reference to the process
group (the loop's `destroy_process_group()` dropped the others), and the reducer's destructor runs the gloo
group's destructor with the GIL held. That destructor joins gloo's worker threads, one of which is still
freeing a tensor of the last collective and waits for the GIL: a deadlock, now and then. A process group
freed from its own Python object releases the GIL while it is destroyed, so `hold_until_exit` keeps one
reference until exit and lets go of it there, while the interpreter is still whole."""

from __future__ import annotations

import atexit
import gc


def hold_until_exit() -> None:
    """In a rank of a multi-process run, keeps the default process group alive until exit and then ends
    it (`_release`); nothing otherwise. Called where a training run has its process group and the seam is
    ours: the `opfa` policy's construction (any `lerobot-train` of it) and the dataset factory of
    `lerobot-opfa train` (any policy), `galr pretrain`."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        atexit.register(_release, [dist.group.WORLD])


def _release(held: list) -> None:
    """Ends the group if training left it up, then drops the held reference, so that the group's
    destructor runs here (GIL released) and not in a reducer's destructor or in interpreter teardown."""
    import torch.distributed as dist

    if dist.is_initialized():
        dist.destroy_process_group()
    held.clear()
    gc.collect()
