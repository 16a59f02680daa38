"""The xarray classes `vcirun.open_results` returns: xarray's Dataset and DataArray whose `.sel`
also takes the results' `method` dimension by keyword.

A results table's first dimension is named `method` (the paper's method labels), and `method` is
also the keyword of xarray's own `.sel(..., method="nearest")` (inexact matching), so plain xarray
reads `ds.l2_error.sel(method="MCVAA", h=0.01)` as a fill method and fails ("Invalid fill method").
Here a `method=` value that is not one of xarray's fill methods (nor None) is a label of the method
dimension; a fill method keeps xarray's meaning (`.sel(h=0.011, method="nearest")` is inexact
matching on h, and `.sel({"method": "MCVAA", "h": 0.011}, method="nearest")` would apply it to the
string labels too, which xarray refuses). Everything else is xarray's own: the subclasses define empty __slots__ as xarray asks, live at
module level so datasets pickle (dask, multiprocessing), and operations that build new objects
return these classes or plain xarray ones.
"""
from __future__ import annotations

import xarray as xr

__all__ = ["ResultsDataset", "ResultsDataArray", "FILL_METHODS"]

FILL_METHODS = frozenset({"nearest", "pad", "ffill", "backfill", "bfill"})


def _split_method(dims, indexers, method, indexers_kwargs):
    """(indexers, method, indexers_kwargs) with a non-fill `method=` value moved to the `method`
    dimension's indexers (xarray takes indexers as a dict or as keywords, not both: one dict here)."""
    if method is None or "method" not in dims or (isinstance(method, str) and method in FILL_METHODS):
        return indexers, method, indexers_kwargs
    idx = dict(indexers or {})
    if "method" in idx or "method" in indexers_kwargs:
        raise ValueError("sel: the method dimension is given twice (as method= and in the indexers)")
    for k, v in indexers_kwargs.items():
        if k in idx:
            raise ValueError(f"sel: the {k} dimension is given twice")
        idx[k] = v
    idx["method"] = method
    return idx, None, {}


class ResultsDataArray(xr.DataArray):
    __slots__ = ()

    def sel(self, indexers=None, method=None, tolerance=None, drop=False, **indexers_kwargs):
        indexers, method, indexers_kwargs = _split_method(self.dims, indexers, method, indexers_kwargs)
        return super().sel(indexers, method=method, tolerance=tolerance, drop=drop, **indexers_kwargs)


class ResultsDataset(xr.Dataset):
    __slots__ = ()

    def sel(self, indexers=None, method=None, tolerance=None, drop=False, **indexers_kwargs):
        indexers, method, indexers_kwargs = _split_method(self.dims, indexers, method, indexers_kwargs)
        return super().sel(indexers, method=method, tolerance=tolerance, drop=drop, **indexers_kwargs)

    def _construct_dataarray(self, name):
        da = super()._construct_dataarray(name)
        try:  # the fast path of xarray's own DataArray._replace
            return ResultsDataArray(da.variable, da._coords, name=da.name, indexes=da._indexes, fastpath=True)
        except (AttributeError, TypeError):  # an xarray without these internals: a plain DataArray
            return da
