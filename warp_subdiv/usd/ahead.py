"""Meshes of a bake refined ahead of the writer on worker threads (:class:`Ahead`), so that a bake keeps every
core busy while the main thread writes.
"""
from __future__ import annotations

import collections

from ..runtime import phases as _phases
from ..runtime import threads as _threads
from ..runtime.estimate import total_bytes

#: Refined vertices from which a mesh is refined ahead of the writer on a worker thread (:class:`Ahead`);
#: smaller ones cost less to refine than to hand over (and are batched, :class:`~warp_subdiv.usd.batching.Batches`).
AHEAD_VERTICES = 16_384
#: Bytes of results (points, normals, face-varying values) a worker computes ahead per mesh, besides its
#: refiner; time samples beyond it are evaluated by the writer as they are written.
AHEAD_BYTES = 256 * 2**20


class Ahead:
    """Meshes refined ahead of the writer on worker threads, so that a bake keeps every core busy: while the
    main thread writes one mesh (Vt arrays, specs; usd-core holds the GIL there), workers analyse and refine
    the next ones (Warp's CPU launches and numpy's large array operations release the GIL).

    ``bake``: the :class:`~warp_subdiv.usd.refine.Bake` whose meshes these are. A mesh is refined ahead when
    its topology does not change over time, it is not batched (:class:`~warp_subdiv.usd.batching.Batches`)
    and it has at least :data:`AHEAD_VERTICES` refined vertices. A worker builds the mesh's refinement
    (:meth:`Bake.refinement <warp_subdiv.usd.refine.Bake.refinement>`: the refiner, its topology and face map,
    exactly as the writer would) and evaluates what the writer will ask of it
    (:meth:`~warp_subdiv.usd.refinement.MeshRefinement.run_ahead`: positions and face-varying channels, by
    their inputs); the writer takes the refinement when it reaches the mesh (:meth:`take`) and writes it as it
    would have, so the layer is the same with or without workers. A mesh whose inputs fail is left to the
    writer, which reports the error.

    Workers: :func:`warp_subdiv.runtime.threads.default_threads` (``--threads``, ``WARP_SUBDIV_THREADS``, the
    cores), on the CPU only; one thread means none. At most ``workers`` meshes are in flight besides the one
    being written, fewer where ``max_memory`` does not allow their working sets at once (:attr:`concurrent`:
    the meshes held at once, which the memory prediction counts)."""

    def __init__(self, bake, max_memory=None):
        import warp as wp

        from ..runtime.estimate import memory_limit

        p, batches = bake.plan, bake.batches
        self.bake = bake
        self.futures: dict = {}
        self.writing = None  # the mesh the writer took last (it holds its working set while writing it)
        self.pool = None
        self.concurrent = 1
        kept = set(bake.reused) | set(bake.partial)  # kept by an earlier run (resume), whole or some samples
        self.queue = collections.deque(
            i for i, (sp, e) in enumerate(zip(p.prims, p.estimates))
            if not sp.topologies and e.final.vertices >= AHEAD_VERTICES
            and (batches is None or i not in batches.chunk_of) and i not in kept)
        workers = _threads.default_threads()
        if workers < 2 or len(self.queue) < 2 or not wp.get_device(bake.device).is_cpu:
            return
        limit_bytes = memory_limit(max_memory)
        depth = workers
        while depth and limit_bytes is not None and total_bytes(p.estimates, depth + 1) > limit_bytes:
            depth -= 1
        if depth == 0:
            return
        from concurrent.futures import ThreadPoolExecutor

        from ..evaluator import load_kernels

        load_kernels(wp.get_device(bake.device))  # loaded once, before threads launch them
        self.depth, self.concurrent = depth, depth + 1
        # the working sets the prediction counts (the largest `concurrent` of the bake): smaller meshes may be
        # held more at once within them (see _fill)
        self.budget = sum(sorted((e.working_bytes for e in p.estimates), reverse=True)[:self.concurrent])
        self.pool = ThreadPoolExecutor(workers, thread_name_prefix="warp-subdiv-bake")

    def _fill(self, i: int) -> None:
        """Keep meshes from ``i`` on in flight: :attr:`depth` of them, and more while the working sets held at
        once (the writer's mesh, those in flight or refined and not yet taken, the next one) stay within
        :attr:`budget`, the largest :attr:`concurrent` working sets of the bake that the memory prediction
        counts. So a large mesh's refinement no longer leaves a worker idle once the small meshes after it
        are done (a count of meshes alone stops at :attr:`depth` of them), and the prediction still holds."""
        while self.queue and self.queue[0] < i:
            self.queue.popleft()
        working = [e.working_bytes for e in self.bake.plan.estimates]
        held = sum(working[j] for j in self.futures) + (working[self.writing] if self.writing is not None else 0)
        while self.queue and (len(self.futures) < self.depth or held + working[self.queue[0]] <= self.budget):
            j = self.queue.popleft()
            held += working[j]
            self.futures[j] = self.pool.submit(_phases.bound(self._refine, j))

    def _refine(self, i: int):
        """A worker's job: the refinement of mesh ``i``, evaluated ahead; None where anything fails (the writer
        builds it again and reports the error)."""
        bake = self.bake
        sp = bake.plan.prims[i]
        try:
            with _threads.inline():
                refinement = bake.refinement(i, sp)
                refinement.run_ahead(sp.face_varying_mode if sp.scheme != "bilinear" else None,
                                     defaults=not bake.samples_only, budget=AHEAD_BYTES)
            return refinement
        except Exception:  # noqa: BLE001 (reported by the writer, which builds the refinement again)
            return None

    def take(self, i: int):
        """The refinement of mesh ``i`` refined ahead (waiting for its worker), or None."""
        if self.pool is None:
            return None
        self._fill(i)
        future = self.futures.pop(i, None)
        self.writing = i
        self._fill(i + 1)
        if future is None:
            return None
        with _phases.phase("waiting"):
            return future.result()

    def close(self) -> None:
        """Cancel what has not started and wait for the running jobs (nothing runs after the bake returns)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None
            self.futures.clear()
