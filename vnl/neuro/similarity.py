"""The RDM comparisons under their earlier name: `vnl.neuro.rdm`."""

from vnl.neuro.rdm import COMPARISONS, RDM_METHODS, compare_layers, rdms

__all__ = ["COMPARISONS", "RDM_METHODS", "compare_layers", "rdms"]
