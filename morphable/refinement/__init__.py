"""Reconstruction by inverting a renderer (paper Sec. 3.3) and face editing.

Starting from a landmark fit (:func:`morphable.fitting.fit_landmarks`: identity alpha,
expression beta, camera pose theta), the steps, each usable alone:

1. :func:`face_crop` / :func:`crop_camera` / :func:`crop_image` (:mod:`.crop`): the
   FFHQ-style square (:func:`face_frame`) around the fitted landmarks (the framing of the
   neural plugin's training data), resized to the renderer's resolution, with FFHQ's
   mirrored and faded background where it leaves the photo (:func:`pad_like_ffhq`, as in
   the training crops), and the fit's camera re-expressed in that crop;
2. :func:`~.problem.set_up`: the visibility of the fitted mesh in the crop is cast once
   (open3d); the camera-frame normal map ``n~(alpha, beta, theta)`` is then differentiable
   in the coefficients (:meth:`morphable.MorphableModel.vertices` on torch tensors) and a
   pose increment (axis-angle) through :func:`morphable.raster.normal_map`;
3. :func:`~.problem.start`: the geometry starts at the fit, the appearance where the
   renderer's ``initial_appearance`` hook puts it (:class:`morphable.renderer_plugins.RendererBase`:
   for ``gar`` ``z <- V(crop)`` when its inverter is available, ``eps <- 0``; for
   ``classical`` albedo = mean colour of the face pixels and a uniform white SH environment);
4. :func:`refine` (:mod:`.inversion`): Adam over alpha, beta, theta (+ a translation offset)
   and the appearance on the loss of :mod:`.loss`

   ``L_f = lambda_photo ||render(n~) - I||^2 + lambda_feat sum_i ||F_i(render) - F_i(I)||^2
   + lambda_eps ||eps||^2 + lambda_lmk ||proj(landmarks) - l||^2 + lambda_alpha ||alpha||^2
   + lambda_beta ||beta||^2``

   with the photometric terms over the pixels the renderer's ``photometric_mask`` names
   (the whole crop for ``gar``, which renders a background; the fitted face pixels for
   ``classical``) and the appearance prior (``eps``) the renderer's ``appearance_prior``.
   ``F_i`` are the features a renderer plugin offers (the encoder stages of the neural
   plugin's aux normal network N) unless a TorchScript feature network (e.g. VGG, returning a
   list of feature maps) is given — no VGG weights can be downloaded here;
5. :func:`edit` (:mod:`.editing`): the recovered face under another pose / expression,
   re-rendered with the recovered appearance.

Units: mm and degrees in the results; images (H, W, 3) float in [0, 1] (or uint8). torch is
imported only when a refinement runs.
"""
from .crop import crop_camera, crop_image, face_crop, face_frame, pad_like_ffhq
from .editing import Refinement, edit
from .inversion import refine, refine_frames, refine_shared
from .mask import MIN_COVERAGE, pixel_weights
from .loss import DEFAULT_WEIGHTS, NO_PHOTOMETRIC, landmark_trust, parse_loss_weights

__all__ = ["face_frame", "face_crop", "crop_camera", "crop_image", "pad_like_ffhq", "landmark_trust",
           "refine", "refine_shared", "refine_frames", "pixel_weights", "MIN_COVERAGE", "edit", "Refinement", "DEFAULT_WEIGHTS", "NO_PHOTOMETRIC",
           "parse_loss_weights"]
