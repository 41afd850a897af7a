"""The sampling core every product shares: pose sets (:mod:`.poses`), one sample's chain
press -> render -> noise -> perceive (:mod:`.chain`), sweeps over a pose set on local workers or
Dask (:mod:`.sweep`, :mod:`.executor`), the resumable datasets they fill (:mod:`.dataset`) and
what made them (:mod:`.versions`, :mod:`.runlog`).
"""
