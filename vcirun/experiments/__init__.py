"""Experiment runner: YAML sweep configs (`config`), parallel execution with resume (`sweep`), one
HDF5 file per sweep (`vcirun.io`, schema in docs/reference/results_schema.md), metrics, figures and tables;
studies that a sweep grid cannot express (`studies`, `workprecision`: `vcirun study CONFIG`).

Submodules are imported on demand (`from vcirun.experiments import sweep`) so that importing the
package stays cheap; none of them imports sympy.
"""
