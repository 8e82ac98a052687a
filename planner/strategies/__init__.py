"""The planning strategies, one module each, registered under their names (:mod:`planner.strategy`).

"delays" and "detours" (:mod:`.delays`, the departure-delay CSP), "evasion" (:mod:`.evasion`:
the CSP with clear detours and step-aside moves), "cluster" (:mod:`.cluster`),
"prioritized" (:mod:`.prioritized`, thesis Algorithm 6), "via" (:mod:`.via`) and
"reversed" (:mod:`.reversed`: the delay strategies on the time-reversed leg) and "sequenced"
(:mod:`.sequenced`: straight moves and one-stop detours planned arm by arm on a time grid).
"""

from planner.registry import register
from planner.strategies.cluster import Cluster
from planner.strategies.delays import Delays, Detours
from planner.strategies.evasion import Evasion
from planner.strategies.prioritized import Prioritized
from planner.strategies.reversed import Reversed, reverse_trajectories
from planner.strategies.sequenced import Sequenced
from planner.strategies.via import Via
from planner.strategy import FirstOf

DELAYS = register(Delays())
CLUSTER = register(Cluster())
DETOURS = register(Detours())
EVASION = register(Evasion())
PRIORITIZED = register(Prioritized())
SEQUENCED = register(Sequenced())
VIA = register(Via())
REVERSED = register(Reversed(FirstOf("delays", (DELAYS, CLUSTER, DETOURS)), name="reversed"))

__all__ = ["Cluster", "Delays", "Detours", "Prioritized", "Reversed", "Sequenced", "Via", "reverse_trajectories",
           "Evasion", "DELAYS", "CLUSTER", "DETOURS", "EVASION", "PRIORITIZED", "SEQUENCED", "VIA", "REVERSED"]
