"""Output arrays of a world's bulk stages kept from one draw to the next (:class:`WorldBuffers`).

Most of a simulated world's memory is in the arrays that :func:`envs.sim.trajectory.generate_truth` (truth at the
IMU rate) and :func:`envs.sim.imu.simulate_imu` (IMU samples and error records) allocate, B x N x 3 each; the
GNSS ranging and receiver stages (:mod:`envs.sim.gnss_stages`) take their (B, M, C) channel arrays from it too. An env
core draws a new world at every reset and keeps only part of it (:mod:`envs.prepared`), so without buffers the
operating system maps, zeroes and unmaps those arrays at every reset (system time: ``time.process_time`` counts
it, ``bench_envs.py``'s CPU columns show it). Handing the same arrays out again removes that work; the env core
keeps one :class:`WorldBuffers` (``TuningCore.world_buffers``, released by the env's ``close()``).

An array is handed out again only when nothing else references it (``sys.getrefcount``: no world, no view, no
copy of the reference anywhere), so a world the caller still holds is never overwritten; otherwise a fresh array
is allocated (and kept instead).
"""
from __future__ import annotations

import sys

import numpy as np


class WorldBuffers:
    """Named arrays reused across world draws when nobody else holds them (see the module docstring).

    The memory stays allocated between draws (the largest world drawn so far); :meth:`clear` releases it.
    """

    def __init__(self):
        self._arrays: dict = {}

    def empty(self, name: str, shape, dtype) -> np.ndarray:
        """An uninitialized array like ``np.empty(shape, dtype)``: the one kept under ``name`` when it has this
        shape and dtype and nothing else references it, else a new one (then kept under ``name``)."""
        shape, dtype = tuple(int(s) for s in shape), np.dtype(dtype)
        a = self._arrays.get(name)
        # references: the dict, the local name, getrefcount's argument; any world or view adds one
        if a is not None and a.shape == shape and a.dtype == dtype and sys.getrefcount(a) <= 3:
            return a
        a = None
        self._arrays.pop(name, None)                        # ours is released before the new one is allocated
        a = self._arrays[name] = np.empty(shape, dtype)
        return a

    def __deepcopy__(self, memo) -> "WorldBuffers":
        return WorldBuffers()                               # a copy (a cloned env core) starts without memory

    def __reduce__(self):
        return WorldBuffers, ()                             # nor is the memory pickled

    @property
    def nbytes(self) -> int:
        """Bytes held."""
        return sum(a.nbytes for a in self._arrays.values())

    def clear(self) -> None:
        """Release every array (a later draw allocates anew)."""
        self._arrays.clear()


def empty(buffers: WorldBuffers | None, name: str, shape, dtype) -> np.ndarray:
    """``buffers.empty(name, shape, dtype)``, or ``np.empty(shape, dtype)`` without buffers."""
    return np.empty(shape, dtype) if buffers is None else buffers.empty(name, shape, dtype)
