"""The neural plugin of morphable: the Generative Adversarial Renderer (GAR).

``G(n, z, eps)`` renders a face image from a camera-frame normal map ``n`` and a latent
code ``z`` (plus per-layer noise ``eps``), after "Inverting Generative Adversarial Renderer
for Face Reconstruction" (Piao et al., CVPR 2021). Modules:

- :mod:`neural.config` — the ``tiny`` (64 px, 2 CPU cores) and ``base`` (256 px, GPU) configs;
- :mod:`neural.gar` — mapping network, modulated convolutions, Normal Injection, generator,
  residual discriminator;
- :mod:`neural.losses` — L_n, L_ldmk, L_id, L_adv (non-saturating) with R1, weighted total;
- :mod:`neural.auxnets` — the frozen auxiliary networks N (normals), P (face mask),
  L (landmarks), R (identity), their loader and ``python -m neural.auxnets.train``;
- :mod:`neural.data` — synthetic renders with exact labels, aligned image folders;
- :mod:`neural.real_faces` — the packed real-photo set (aligned crops with their fits' normal
  maps, masks and landmarks) and its batches;
- :mod:`neural.train` — ``python -m neural.train --config tiny --out runs/tiny``;
- :mod:`neural.checkpoint` — the committed weights' default paths, loading a network or
  the generator from a checkpoint file, one-line errors;
- :mod:`neural.gar_renderer` — ``GARRenderer``, the ``gar`` plugin of :mod:`morphable.renderer_plugins`,
  with its inversion hooks (z from V);
- :mod:`neural.inverter` — the inverting network V (image -> latent ``z``), its loss and files;
- :mod:`neural.train_inverter` — ``python -m neural.train_inverter``: V against a frozen GAR.

Reconstruction by inverting a renderer and editing are the core's
(:mod:`morphable.refinement`); the GAR's quality report and ablations are evaluation
(:mod:`evaluation.gar_quality`, :mod:`evaluation.gar_ablation`).

This package needs torch (``pip install morphable[neural]``); ``morphable`` itself never
imports it: it finds the renderer through the ``morphable.renderers`` entry point. Images
are (B, 3, H, W) float tensors in [-1, 1]; normal maps are (B, 3, H, W) unit vectors in
the camera frame (x right, y up, z towards the viewer) and zero outside the face.
"""
