"""Particle count and memory estimates, checked before anything is allocated."""
from __future__ import annotations

from decomposition import collective
from parsph.errors import SceneError
from parsph.scene.geometry import estimate_count

#: Bytes per particle of what every run holds: core fields, halo share, CSR neighbour
#: lists (int32 per neighbour) and the cell list, by dimension.
BASE_BYTES = {2: 100 + 4 * 24 + 40, 3: 120 + 4 * 70 + 40}
#: Extra bytes per particle of each stage (its fields and, for implicit stages, matrices).
#: iisph: its fields, both systems' scalar matrices with their hypre copies and AMG
#: hierarchies, the viscous pairs' coefficients. coupled: the same with the solid's view
#: and TLSPH's pairs: a 3D coupled tank rose by 1.81 kB per particle in all at 1.1e5
#: particles on one rank, 1.92-1.97 kB on two and 1.95 kB at 1.0e6 on two
#: (jobs/bench_memory.py, docs/benchmarks.md, 2026-12-05); the estimate (2,170 B with
#: BASE_BYTES) is 10 % above. 2D (~24 neighbours against ~57) is taken at the same
#: figures, an upper bound.
STAGE_BYTES = {"kinematics": 0, "density": 8, "iisph": 3300, "tlsph": 1200, "coupled": 1730}
#: More bytes per particle with ``fluid.viscous_operator = "assembled"`` (the dim x dim
#: blocks held as CSR work arrays, PETSc's AIJ and hypre's copy with its hierarchy: the
#: same 3D tank rose by 14.2 kB per particle).
ASSEMBLED_VISCOUS_BYTES = {2: 3000, 3: 9300}
#: A scene may use at most this share of a node's memory.
MEMORY_SHARE = 0.8


def node_memory_bytes() -> int:
    """Physical memory of this node (Linux /proc/meminfo; 0 if unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def ranks_on_this_node(comm) -> int:
    from decomposition.comm import node_comm

    return node_comm(comm).size


def estimate(comm, scene, specs) -> dict:
    """Particle count (upper bound from the lattices) and memory, total and per rank."""
    n = estimate_count(scene)
    dim = scene.domain.dim
    per_particle = BASE_BYTES[dim] + sum(STAGE_BYTES.get(s.name, 0) for s in specs)
    if any(s.name in ("iisph", "coupled") for s in specs) \
            and scene.fluid.viscous_operator == "assembled":
        per_particle += ASSEMBLED_VISCOUS_BYTES[dim]
    total = n * per_particle
    return {"particles": n, "bytes_per_particle": per_particle, "bytes_total": total,
            "bytes_per_rank": total / comm.size, "ranks": comm.size}


def check_budget(comm, scene, specs) -> dict:
    """Collective: refuse a scene that needs absurd particle counts or memory.

    Raises
    ------
    SceneError
        With the estimate and what to change (particle size, rank count).
    """
    with collective(comm):  # node memory differs between nodes: agree on the outcome
        est = _check(comm, scene, specs)
    return est


def _check(comm, scene, specs) -> dict:
    est = estimate(comm, scene, specs)
    if est["particles"] > scene.run.max_particles:
        raise SceneError(
            f"{scene.source}: about {est['particles']:.3g} particles at domain.particle_size = "
            f"{scene.domain.particle_size} m exceed run.max_particles = "
            f"{scene.run.max_particles:.3g}; use a larger particle size or raise run.max_particles")
    mem = node_memory_bytes()
    local = ranks_on_this_node(comm)
    # Every node must hold its ranks' share; take the tightest node.
    need = est["bytes_per_rank"] * local
    if mem and need > MEMORY_SHARE * mem:
        raise SceneError(
            f"{scene.source}: the scene needs about {est['bytes_total'] / 2**30:.3g} GiB "
            f"({est['particles']:.3g} particles x {est['bytes_per_particle']} B); the {local} "
            f"rank(s) on this node would need {need / 2**30:.3g} GiB of its "
            f"{mem / 2**30:.3g} GiB; use more nodes or a larger domain.particle_size")
    est["node_memory"] = mem
    return est
