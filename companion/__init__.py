"""Onboard companion: bearing-only target following (Li et al., IEEE T-RO 2023).

The numerical core (estimators, guidance, attitude mapping, pipeline) is pure
numpy with no I/O and no clock of its own; adapters to MAVLink and Zenoh live
at the edge.
"""
