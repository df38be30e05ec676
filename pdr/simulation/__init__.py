"""Simulated responders: raw phone IMU, magnetometer and barometer streams with their truth.

A walker holds its phone flat in front (body x right, y forward, z up) and walks a route
of waypoints — given (:class:`Route`) or drawn at random inside a building's bounds — at
its own cadence, taking corners in a smooth curve, sharp ones on the spot, stairs between
floors, pauses where the route says, and, on request, stopping (:meth:`SimulatedWalker.stand_still`)
or collapsing (:meth:`SimulatedWalker.collapse`, man-down). Every sample is a closed-form
function of its index (equations in :mod:`pdr.simulation.motion`), so streaming batches of
any size equal one long call, and :class:`WalkerFleet` computes a thousand walkers in one
numpy pass (for the load benchmark and ``firetrack simulate``).

    walker = SimulatedWalker("ff-1", route=None, settings=WalkerSettings(), rng_seed=7)
    batch = walker.next_batch(10)          # 0.1 s at 100 Hz: batch.acc, .gyr, .mag, .pressure, truth
    fleet = WalkerFleet(1000, seed=1)
    arrays = fleet.next_arrays(10)         # (1000, 10, 3) ...; fleet.next_batches(10) -> [SimBatch]

Modules: :mod:`~pdr.simulation.settings` (settings, routes), :mod:`~pdr.simulation.motion`
(the maths), :mod:`~pdr.simulation.plan` (routes -> rows), :mod:`~pdr.simulation.strides` (a
walker's gait and step lengths), :mod:`~pdr.simulation.fleet` (streaming).
"""
from pdr.simulation.fleet import (
    FleetBatch,
    SimBatch,
    SimulatedWalker,
    WalkerFleet,
    simulate_walk,
    walker_seed,
)
from pdr.simulation.settings import (
    Route,
    WalkerSettings,
    random_route,
    random_waypoints,
)
from pdr.simulation.strides import WalkerTraits

__all__ = [
    "WalkerSettings", "Route", "random_route", "random_waypoints", "SimulatedWalker", "WalkerFleet",
    "SimBatch", "FleetBatch", "WalkerTraits", "simulate_walk", "walker_seed",
]
