"""Tactile object recognition and marker selection on the simulated fingertip
(docs/recognition.md): the three reference systems that turn contacts into object identity or
decide which sensing elements matter.

Modules, in the order the data flows:

* :mod:`.library` the object library (``scenes/objects/library.toml``), :mod:`.shapes` its
  outlines, :mod:`.object_indenters` the rounded prisms, torus and bounded mesh the FEM
  presses, :mod:`.compliance` the soft ball's Hertzian spring in series with the pad;
* :mod:`.contacts` contacts through the shared chain (:class:`tactip_lab.sampling.chain.Chain`)
  into a resumable data set (:mod:`.store`); :mod:`.features` the marker field and difference
  images;
* :mod:`.bof` and :mod:`.fusion`: bag of features, Bayesian fusion, expected information gain;
  :mod:`.moments` the moment bag of words + SVM; :mod:`.cnn` a small CNN (PyTorch);
* :mod:`.id3` and :mod:`.boost`: ID3 marker selection and LogitBoost stumps;
* :mod:`.studies`, :mod:`.recognise`, :mod:`.select`, :mod:`.report`: the studies, their
  outputs and the ``tactip recognise`` / ``tactip select-markers`` commands
  (:mod:`.recognition_cli`).

Nothing heavy is imported here: ``tactip --help`` stays fast.
"""
