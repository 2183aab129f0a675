"""Neuroscience tools for `vnl record` recordings: NWB export (`nwb`), encoding and decoding models
(`encoding`, `decoding`), behavioural states (`states`), RDMs with rsatoolbox (`similarity`) and
Dynamical Similarity Analysis (`dsa`), on the behaviour features of `features`.

These modules import their third-party tools (pynwb, scikit-learn, hmmlearn, rsatoolbox, ...) on
use; nothing that `vnl train` imports imports them.
"""
