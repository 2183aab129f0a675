"""The names the tutorials use for a recording's PCA: `vnl.neuro.pca` (the method) and
`vnl.recording.read` (the reader, here `open_recording`)."""

from vnl.neuro.pca import pca, pca_figure
from vnl.recording import read as open_recording

__all__ = ["open_recording", "pca", "pca_figure"]
