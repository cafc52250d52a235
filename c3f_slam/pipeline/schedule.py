"""When and how much of the global keyframe graph is optimised (``OptimizationConfig``).

After a keyframe that adds a loop edge or merges components (odometry-only keyframes are
chained), the component of the new keyframe is optimised, and always at the end. Rate limit
(a deviation from the paper on big maps): while the map has fewer than ``small_map``
keyframes every such keyframe optimises; beyond, an optimisation waits until the keyframes
added since the last one are at least ``growth`` x the nodes it would optimise (the new
keyframe's component, at most ``max_nodes``): a geometric schedule (about 5 % growth) while
whole components are optimised, a fixed gap for windows; a skipped trigger is remembered and
runs at the next due keyframe. A component larger than ``max_nodes`` is optimised in a
bounded window (breadth first over the graph from the new keyframe(s)) with the rest held
fixed, because Open3D's solver is dense (cubic in the nodes); ``window_boundary_edges``
bounds, per window node, the edges to fixed newer keyframes. At the end the main component
(and each other component that is written, :mod:`c3f_slam.pipeline.components`) is
optimised whole when it has at most ``final_nodes`` keyframes, else by one sweep of
overlapping ``max_nodes`` windows in keyframe order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from c3f_slam.config import OptimizationConfig
from c3f_slam.posegraph import PoseGraph, PoseGraphConfig


@dataclass
class OptimizationCounts:
    """What the schedule did (summary.json)."""

    optimizations: int = 0
    windowed: int = 0  #: of them, windows of a larger component
    max_nodes: int = 0  #: the largest number of nodes optimised at once


class OptimizationSchedule:
    """Runs the global optimisations of ``graph`` by the rules above; ``n_keyframes`` is the
    number of keyframes (nodes) in the map when a method is called."""

    def __init__(self, cfg: OptimizationConfig, posegraph: PoseGraphConfig, graph: PoseGraph) -> None:
        self.cfg = cfg
        self.posegraph = posegraph
        self.graph = graph
        self.counts = OptimizationCounts()
        self.pending = False  #: a loop / merge waits for the next due optimisation
        self.keyframes_at_last = 0  #: keyframes when the graph was last optimised

    def after_keyframe(self, node: int, trigger: bool, n_keyframes: int) -> None:
        """Keyframe ``node`` was added (or a fragment hung off it); ``trigger``: it added a
        loop edge or merged components."""
        if self.cfg.every_keyframe:
            self.pending |= trigger
            if self.pending and self.due(node, n_keyframes):
                self.optimize(node, n_keyframes)

    def due(self, node: int, n_keyframes: int) -> bool:
        """Whether a pending loop / merge may be optimised now: always on small maps or with
        ``growth=None``; else once the keyframes added since the last optimisation are at
        least ``growth`` x the nodes an optimisation would take now. Each optimisation of s
        nodes (cost ~ s^3) thus follows >= growth * s keyframes: constant amortised cost."""
        growth = self.cfg.growth
        if growth is None or n_keyframes < self.cfg.small_map:
            return True
        size = self.graph.component_size(node)
        if self.cfg.max_nodes is not None:
            size = min(size, self.cfg.max_nodes)
        return n_keyframes - self.keyframes_at_last >= max(1, math.ceil(growth * size))

    def optimize(self, node: int | None, n_keyframes: int) -> list[int]:
        """Optimise the component of ``node`` (None: the main one): whole, anchored at its
        oldest node, when it has at most ``max_nodes`` keyframes; else a window of that many,
        breadth first from ``node`` and the keyframes added since the last optimisation, with
        the rest held fixed. Returns the pruned edges."""
        g = self.graph
        if g.n_nodes == 0 or not g.edges:
            return []
        if node is None:
            node = g.component_oldest(g.main_root)
        cap = self.cfg.max_nodes
        seeds = [node]
        if cap is not None:
            recent = range(n_keyframes - 1, self.keyframes_at_last - 1, -1)
            seeds += [k for k in recent if k != node and g.connected(k, node)][: max(cap // 4, 1)]
        window = g.reachable(seeds, None if cap is None else cap + 1)
        whole = cap is None or len(window) <= cap  # reachable() found the whole component
        return self._run(window if whole else window[:cap], whole, g.component_oldest(node), n_keyframes)

    def finish(self, n_keyframes: int, node: int | None = None) -> None:
        """The final optimisation of the component of ``node`` (None: the main one), whole
        or by one sweep of windows."""
        g = self.graph
        if not g.edges:
            return
        oldest = g.component_oldest(g.main_root if node is None else node)
        cap = self.cfg.final_nodes
        comp = g.reachable([oldest], None if cap is None else cap + 1)
        if cap is None or len(comp) <= cap:
            self._run(comp, True, oldest, n_keyframes)
            return
        members = g.component_nodes(oldest)
        w = min(self.cfg.max_nodes or cap, cap)
        step = max(w // 2, 1)
        for start in range(0, max(len(members) - w, 0) + step, step):
            self._run(members[start:start + w], False, oldest, n_keyframes)

    def _run(self, nodes: list[int], whole: bool, oldest: int, n_keyframes: int) -> list[int]:
        """Optimise ``nodes``: a whole component (anchored at its oldest node), or a window
        of one with its other neighbours fixed (``oldest`` fixed too)."""
        if len(nodes) < 2:
            return []
        if whole:
            res = self.graph.optimize(self.posegraph, reference_node=min(nodes))
        else:
            res = self.graph.optimize(self.posegraph, reference_node=oldest, nodes=nodes,
                                      max_boundary_edges=self.cfg.window_boundary_edges)
            self.counts.windowed += 1
        self.counts.optimizations += 1
        self.keyframes_at_last = n_keyframes
        self.counts.max_nodes = max(self.counts.max_nodes, len(res.optimized_nodes))
        self.pending = False
        return res.pruned
