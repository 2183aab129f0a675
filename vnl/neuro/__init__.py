"""The methods that analyse recordings, each a module behind one registry (`registry`: what
`vnl analyze --method` and `vnl compare --measure` dispatch to).

- one recording (`vnl analyze`): `pca`, `encoding` and `decoding` models, behavioural `states`,
  sharing the cross-validation of `crossval`;
- two networks' layers on the same steps (`vnl compare`, `vnl.compare`): `cka`, `rsa`, `rdm`
  (rsatoolbox), `dsa` (Dynamical Similarity Analysis).

The data they read is `vnl.recording`'s (the model, the behaviour features, the readers). These
modules import their third-party tools (scikit-learn, hmmlearn, rsatoolbox, ...) on use; nothing
that `vnl train` imports imports them. `nwb` and `similarity` are the earlier names of
`vnl.recording.nwb` and `rdm`.
"""
