"""Regressors from a dataset's perceived features to its labels: labelled folders in the lab's
layout (:mod:`.bristol`), fitting and scoring (:mod:`.fit`), the feature and order chosen by
cross-validation (:mod:`.cv_select`), charts, and the ``tactip fit | evaluate | features``
commands on any labelled folder.
"""
