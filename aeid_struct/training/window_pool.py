"""Fresh generic training windows simulated by worker processes, one epoch ahead.

Simulating the family's windows (``distributed.block_records``) is numpy and CPU work; on a GPU
the gradient steps take a fraction of it, and one process on one core would leave the GPU idle.
A :class:`WindowPool` runs the blocks on ``workers`` processes (a ``concurrent.futures`` process
pool, started by ``spawn``: the trainer may hold CUDA and torch's threads, which a fork would
copy), and once an epoch's blocks are taken it submits the next epoch's, so they are simulated
while the current one trains. A block is the same whoever simulates it (its generator is seeded
by ``(seed, epoch + 1, block)``), so the run does not depend on the number of workers.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor

import torch

from aeid_struct.training.distributed import block_records

__all__ = ["WindowPool"]


def _one_thread() -> None:
    """A worker simulates one block at a time on one core (the workers are the parallelism)."""
    torch.set_num_threads(1)


class WindowPool:
    """``workers`` processes simulating an epoch's blocks of fresh windows, the next epoch's
    ahead.

    Parameters
    ----------
    family : object
        Picklable; gives ``records(count, steps, rng)``.
    seed, count, window : int
        ``GenericTrainConfig.seed``, ``.count`` and the identifier's window.
    workers : int, >= 1
    """

    def __init__(self, family, seed: int, count: int, window: int, workers: int) -> None:
        self._args = (family, seed, count, window)
        self._pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_one_thread)
        self._pending: dict[tuple[int, int], Future] = {}

    def _submit(self, epoch: int, blocks) -> None:
        for k in blocks:
            if (epoch, k) not in self._pending:
                self._pending[epoch, k] = self._pool.submit(block_records, *self._args, epoch, k)

    def blocks(self, epoch: int, blocks) -> dict:
        """The blocks of ``epoch`` (``distributed.block_records``), waiting for those not done;
        then submits the same blocks of ``epoch + 1``.

        Parameters
        ----------
        epoch : int
        blocks : list of int

        Returns
        -------
        dict
            Block -> ``(y, u)`` float64 arrays.
        """
        self._submit(epoch, blocks)
        got = {k: self._pending.pop((epoch, k)).result() for k in blocks}
        for key in [key for key in self._pending if key[0] < epoch]:   # a resumed run's leftovers
            self._pending.pop(key).cancel()
        self._submit(epoch + 1, blocks)
        return got

    def close(self) -> None:
        """Stop the workers (the blocks submitted ahead are dropped)."""
        for future in self._pending.values():
            future.cancel()
        self._pending.clear()
        self._pool.shutdown(wait=True, cancel_futures=True)
