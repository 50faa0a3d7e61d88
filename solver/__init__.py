"""Design and certify networked predictive controllers for switched plants.

Public names::

    from solver import PlantFamily, design, analyze, simulate
    from solver import Channel, analyze_channel, critical_loss
    from solver import Network

See ``design`` for the methods, ``analyze`` for certificates and verdicts and
``simulate`` for seeded runs of the network of the paper's Sec. II.

In and out: ``PlantFamily.from_statespace`` / ``solver.control_interop`` (python-control),
``solver.matlab`` (.mat and .m files), ``solver.plotting`` (figures).
"""

from .analysis import AnalysisReport, analyze
from .codegen import export_c
from .channel import Channel, ChannelReport, analyze_channel, critical_loss
from .certificates import FarkasCertificate, UncontrollableCertificate
from .design import METHODS, design
from .errors import InvalidInput, SolverFailed
from .lyapunov import Certificate
from .networks import Network
from .plant import PlantFamily
from .result import DesignResult, IterationRecord
from .simulate import SimulationResult, simulate
from .sdpa import export_sdpa

__all__ = [
    "PlantFamily",
    "Network",
    "design",
    "analyze",
    "simulate",
    "export_c",
    "export_sdpa",
    "Channel",
    "analyze_channel",
    "critical_loss",
    "ChannelReport",
    "METHODS",
    "DesignResult",
    "IterationRecord",
    "AnalysisReport",
    "SimulationResult",
    "Certificate",
    "FarkasCertificate",
    "UncontrollableCertificate",
    "InvalidInput",
    "SolverFailed",
]
