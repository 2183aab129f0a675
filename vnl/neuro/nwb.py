"""The NWB export under its earlier name: `vnl.recording.nwb` (the tutorials' `from vnl.neuro import nwb`)."""

from vnl.recording.nwb import inspect, report, serious, write

__all__ = ["inspect", "report", "serious", "write"]
