"""The Generative Adversarial Renderer (GAR), after "Inverting Generative Adversarial Renderer
for Face Reconstruction" (Piao et al., CVPR 2021).

``G(n, z, eps)`` renders a face image from a camera-frame normal map ``n`` and a latent code
``z`` (plus per-layer noise ``eps``). Modules:

- :mod:`.config` — the ``tiny`` (64 px, 2 CPU cores), GPU and ``base`` (256 px) configs;
- :mod:`.networks` — mapping network, modulated convolutions, Normal Injection, generator,
  residual discriminator, :func:`~.networks.load_generator`;
- :mod:`.losses` — L_n, L_ldmk, L_id, L_adv (non-saturating) with R1, weighted total;
- :mod:`.auxnets` — the frozen auxiliary networks N (normals), P (face mask), L (landmarks),
  R (identity), their loader and ``python -m neural.gar.auxnets.train``;
- :mod:`.data` — real photos aligned to the synthetic faces' framing;
  :mod:`.real_faces` — the packed real-photo set and its batches, built by
  ``python -m neural.gar.build_real`` (:mod:`.build_real`);
- :mod:`.train` — ``python -m neural.gar.train --config tiny --out runs/tiny``;
- :mod:`.inverter` — the inverting network V (image -> ``z``); :mod:`.train_inverter` trains
  it against a frozen GAR;
- :mod:`.renderer` — ``GARRenderer``, the ``gar`` plugin of :mod:`morphable.renderer_plugins`
  with its inversion hooks (z from V);
- :mod:`.paths` — where the committed weights live (``neural/gar/weights/``, model card there).

Images are (B, 3, H, W) float tensors in [-1, 1]; normal maps are (B, 3, H, W) unit vectors in
the camera frame (x right, y up, z towards the viewer) and zero outside the face.
"""
