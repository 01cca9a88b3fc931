"""Our landmark network: from a face crop, the 546 surface points of :mod:`neural.faces.points`
(3D convention), a σ each, and a face score.

- :mod:`.network` — the network, its crops and loading its weights;
- :mod:`.data` — training batches drawn from the packs of :mod:`neural.faces`;
- :mod:`.train` — ``python -m neural.landmarks.train`` (CPU and GPU recipes, resumable);
- :mod:`.score` — ``python -m neural.landmarks.score``: the face score refitted with harder
  negatives;
- :mod:`.detector` — ``NetworkDetector``, the ``network`` detector of
  :mod:`morphable.detection` (entry point ``morphable.landmark_detectors``); the committed
  weights are ``neural/landmarks/weights/landmarks.pt`` (model card there).
"""
