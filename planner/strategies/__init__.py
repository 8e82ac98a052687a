"""The planning strategies, one module each, registered under their names (:mod:`planner.strategy`).

"delays" and "detours" (:mod:`.delays`, the departure-delay CSP), "cluster" (:mod:`.cluster`),
"prioritized" (:mod:`.prioritized`, thesis Algorithm 6), "via" (:mod:`.via`) and
"reversed" (:mod:`.reversed`: the delay strategies on the time-reversed leg).
"""

from planner.strategies.cluster import Cluster
from planner.strategies.delays import Delays, Detours
from planner.strategies.prioritized import Prioritized
from planner.strategies.reversed import Reversed, reverse_trajectories
from planner.strategies.via import Via
from planner.strategy import FirstOf, register

DELAYS = register(Delays())
CLUSTER = register(Cluster())
DETOURS = register(Detours())
PRIORITIZED = register(Prioritized())
VIA = register(Via())
REVERSED = register(Reversed(FirstOf("delays", (DELAYS, CLUSTER, DETOURS)), name="reversed"))

__all__ = ["Cluster", "Delays", "Detours", "Prioritized", "Reversed", "Via", "reverse_trajectories",
           "DELAYS", "CLUSTER", "DETOURS", "PRIORITIZED", "VIA", "REVERSED"]
