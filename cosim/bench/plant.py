"""The plant's own speed: ``Plant.step`` and a bare ``fmi2DoStep`` timed (``python -m
cosim.bench.plant``; `cosim bench` measures the plant in the whole tick)."""

from __future__ import annotations

import statistics
import time

from cosim.plant.fmu import Plant
from cosim.scenario.vehicles import VehicleParams


def bench_step(n: int = 20000, vehicle: VehicleParams | None = None) -> dict[str, float]:
    """Time ``Plant.step`` (set inputs + doStep(5 ms) + get outputs) and a bare doStep.

    Returns medians (and minima) over batches of 1000 steps, in microseconds per step:
    ``{"step_us", "step_us_min", "do_step_us", "do_step_us_min", "n"}``. Report, do not gate:
    on a loaded machine the numbers are dominated by scheduling noise (compare the minima).
    """
    from cosim.scenario.vehicles import MAMBO

    vehicle = MAMBO if vehicle is None else vehicle
    u = vehicle.u_hover
    batch = 1000
    with Plant(vehicle, z0=-1.0, omega0=vehicle.omega_hover) as plant:
        per_step = []
        for _ in range(max(1, n // batch)):
            t0 = time.perf_counter()
            for _ in range(batch):
                plant.step(u, u, u, u)
            per_step.append((time.perf_counter() - t0) / batch * 1e6)
        plant.reset()
        plant.step(u, u, u, u)  # the inputs stay set for the bare doSteps below
        do_step, comp, h = plant._do_step, plant._comp, plant.step_size
        bare = []
        k = plant.k
        for _ in range(max(1, n // batch)):
            t0 = time.perf_counter()
            for _ in range(batch):
                do_step(comp, k * h, h, 1)
                k += 1
            bare.append((time.perf_counter() - t0) / batch * 1e6)
    return {
        "step_us": statistics.median(per_step),
        "step_us_min": min(per_step),
        "do_step_us": statistics.median(bare),
        "do_step_us_min": min(bare),
        "n": float(n),
    }


if __name__ == "__main__":  # python -m cosim.bench.plant  -> prints the benchmark
    print(bench_step())
