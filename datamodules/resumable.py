"""A training sampler and loader that a checkpoint resumes exactly, in the middle of an epoch too.

The order of epoch ``e`` is a permutation drawn from ``(seed, e)`` alone (numpy's SeedSequence),
never from the global RNG, so it is the same whatever ran before. A keyed sampler also hands
each sample a draw (an integer from ``(seed, e)``, per position in the epoch) that the dataset
uses for its own random choices (ContraFeat's frame gap): a sample's randomness then travels
with its index, into loader processes too, and does not depend on when it was fetched
(Lightning fetches one batch ahead of the training step).

With several processes (DDP), each takes every ``replicas``-th sample of the epoch's order from
its ``rank`` on (the order padded, as torch's DistributedSampler pads it, to a multiple of the
processes, so that all make the same number of steps): the processes together see the
single-process order, and a position ``p`` in each process's share is position ``p * replicas``
of the epoch. The sampler is a DistributedSampler, so Lightning leaves it as it is instead of
wrapping it in its own (whose position no checkpoint keeps).

:class:`ResumableLoader` is what Lightning checkpoints: it has ``state_dict``/``load_state_dict``,
so the fit loop saves its state in the checkpoint and loads it before the resumed run fetches
anything. The state is the epoch and how many of its samples the training has used; that count
comes from the trainer's own progress (``progress``), not from the loader, which is ahead of the
training by the batches fetched in advance.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler

#: upper bound (exclusive) of a keyed sample's draw
DRAW_RANGE = 2**62


class ResumableSampler(DistributedSampler):
    """Indices of one epoch in an order fixed by ``(seed, epoch)``; resumable at any position.

    Args:
        length: samples per epoch (the dataset's length).
        seed: the order's seed (the run's seed).
        shuffle: permute the indices (else 0, 1, ...).
        keyed: yield ``(index, draw)`` pairs instead of indices, ``draw`` in [0, :data:`DRAW_RANGE`).
        epoch_of: ``() -> epoch``, asked when an iteration starts (the trainer's epoch). None: the
            epoch :meth:`set_epoch` gave (Lightning calls it at each epoch's start, but from a counter
            that is one ahead after resuming a checkpoint saved at ``max_steps`` in mid-epoch).
        replicas: the training processes (DDP's world size); this one yields its share only.
        rank: this process's rank among them, 0 to ``replicas - 1``.

    :meth:`load_state_dict` makes the next iteration start at the saved position of the saved
    epoch; later ones start at 0.
    """

    def __init__(self, length: int, seed: int, shuffle: bool = True, keyed: bool = False,
                 epoch_of: Callable[[], int] | None = None, replicas: int = 1, rank: int = 0) -> None:
        super().__init__(range(int(length)), num_replicas=int(replicas), rank=int(rank), shuffle=shuffle,
                         seed=int(seed))
        self.length, self.keyed = int(length), keyed
        self.epoch_of = epoch_of
        self._resume_at: tuple[int, int] | None = None  # (epoch, position in this share) to start at once

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def order(self, epoch: int) -> np.ndarray:
        """The indices of ``epoch`` in the order they are yielded (by all processes), (length,) int64."""
        if not self.shuffle:
            return np.arange(self.length, dtype=np.int64)
        return np.random.default_rng([self.seed, epoch]).permutation(self.length)

    def draws(self, epoch: int) -> np.ndarray:
        """The draws of ``epoch``, one per position, (length,) int64."""
        return np.random.default_rng([self.seed, epoch, 1]).integers(0, DRAW_RANGE, size=self.length)

    def _share(self, values: np.ndarray) -> np.ndarray:
        """This process's share of one epoch's ``values`` (padded from the start to ``total_size``)."""
        padded = np.resize(values, self.total_size) if len(values) else values
        return padded[self.rank:self.total_size:self.num_replicas]

    def __len__(self) -> int:
        return self.num_samples

    def __iter__(self) -> Iterator:
        resume_at, self._resume_at = self._resume_at, None
        if resume_at is not None:  # the saved epoch, whatever set_epoch said since
            self.epoch, start = resume_at
        else:
            start = 0
            if self.epoch_of is not None:
                self.epoch = int(self.epoch_of())
        order = self._share(self.order(self.epoch))[start:]
        if not self.keyed:
            yield from (int(i) for i in order)
            return
        draws = self._share(self.draws(self.epoch))[start:]
        yield from ((int(i), int(d)) for i, d in zip(order, draws, strict=True))

    def state_dict(self, position: int = 0, epoch: int | None = None) -> dict[str, int]:
        """``position``: samples this process has used of ``epoch`` (default: the current one);
        saved as the position in the epoch's order (times ``replicas``, at most ``length``)."""
        epoch = self.epoch if epoch is None else int(epoch)
        used = min(int(position) * self.num_replicas, self.length)
        return {"seed": self.seed, "epoch": epoch, "position": used, "length": self.length,
                "replicas": self.num_replicas}

    def load_state_dict(self, state: dict) -> None:
        """Continue at ``state``'s epoch and position (a state of another data size is refused).
        Exact with as many processes as the state was saved with; with another number each
        continues at the first of its samples not before the saved position."""
        if int(state["length"]) != self.length:
            raise ValueError(f"the checkpoint's training data had {state['length']} samples per epoch, "
                             f"this one has {self.length}: it cannot resume where it stopped")
        self.seed, self.epoch = int(state["seed"]), int(state["epoch"])
        used = min(max(int(state["position"]), 0), self.length)
        self._resume_at = (self.epoch, min(-(-used // self.num_replicas), self.num_samples))


class ResumableLoader(DataLoader):
    """A DataLoader over a :class:`ResumableSampler` whose position a Lightning checkpoint keeps.

    Args:
        dataset: the training samples.
        sampler: their order.
        progress: ``() -> (epoch, batches done)``: the epoch the training is in and how many of its
            batches the training steps have used (an epoch that is complete counts as
            ``(epoch + 1, 0)``). None: a state_dict of position 0 in the sampler's epoch.
        kwargs: DataLoader's other arguments (``batch_size``, ``num_workers``, ...), but ``shuffle``.
    """

    def __init__(self, dataset: Dataset, sampler: ResumableSampler,
                 progress: Callable[[], tuple[int, int]] | None = None, **kwargs) -> None:
        kwargs.setdefault("generator", torch.Generator().manual_seed(sampler.seed))
        super().__init__(dataset, sampler=sampler, **kwargs)
        self.progress = progress

    def state_dict(self) -> dict[str, int]:
        sampler: ResumableSampler = self.sampler
        if self.progress is None:
            return sampler.state_dict(0)
        epoch, batches = self.progress()
        return sampler.state_dict(min(batches * (self.batch_size or 1), len(sampler)), epoch)

    def load_state_dict(self, state: dict) -> None:
        self.sampler.load_state_dict(state)


__all__ = ["DRAW_RANGE", "ResumableLoader", "ResumableSampler"]
