"""The neural plugin of morphable: learned networks that reach the core only through entry
points.

Three products, each a subpackage, over a thin shared layer:

- :mod:`neural.gar` — the Generative Adversarial Renderer ``G(n, z, eps)`` of "Inverting
  Generative Adversarial Renderer for Face Reconstruction" (Piao et al., CVPR 2021): the
  generator with its Normal Injection, the losses, the auxiliary networks, the inverter V,
  their data and training, and the ``gar`` renderer plugin (entry point
  ``morphable.renderers``);
- :mod:`neural.landmarks` — our landmark network (546 surface points with a σ each and a face
  score): the network, its training batches and training, the face score's refit, and the
  ``network`` detector plugin (entry point ``morphable.landmark_detectors``);
- :mod:`neural.faces` — the face data engine: the point set every pack is labelled in,
  synthetic faces with exact labels, real photos' annotations, the packs and their builders.

Shared by every network: :mod:`neural.training` (the loop, checkpoints with resume, logs),
:mod:`neural.checkpoint` (loading a network from a file with one-line errors),
:mod:`neural.augment` (differentiable augmentation), :mod:`neural.gpu_recipe` (one
command that trains on a lent GPU within a time budget) and :mod:`neural.gpu_travel` (what
travels to that GPU, the rest parked out of the tree).

Imports point downwards: ``gar`` and ``landmarks`` use ``faces`` and the shared layer,
``faces`` only the shared layer and :mod:`morphable`. Reconstruction by inverting a renderer
is the core's (:mod:`morphable.refinement`); the benchmarks are :mod:`evaluation`'s.

This package needs torch (``pip install morphable[neural]``); ``morphable`` itself never
imports it.
"""
