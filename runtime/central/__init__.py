"""The central role, as the parts it holds (:class:`~.scheduler.Central`)."""

from .excuse import Supervision
from .fault import Fault
from .scheduler import Central

__all__ = ["Central", "Fault", "Supervision"]
