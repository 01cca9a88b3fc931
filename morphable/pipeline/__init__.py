"""The photo pipeline: photos, videos and image arrays in, detected points, the fit, an optional
refinement, the texture and overlays, files out. ``morphable fit``, ``fit-batch``, ``track``,
``edit`` and ``profile`` are this package behind a command line.

:func:`fit_images` runs the steps in one call and returns an :class:`ImageFit` (the fit, its
report and the fitted pictures), whose :meth:`ImageFit.write` writes the files. The steps,
each usable alone:

1. :mod:`.inputs` — photos, video frames and arrays as :class:`~.inputs.Picture` objects
   (:func:`~.inputs.pictures`), their landmarks read from files
   (:func:`~.inputs.read_landmark_file`) or arrays (:func:`~.inputs.check_landmarks`),
   or detected (:func:`~.inputs.detect_points`, :mod:`morphable.detection`);
2. :mod:`.fit` — the fit of them all as one person (:func:`morphable.fitting.fit_landmarks`),
   each detector's frames with its noise (:func:`morphable.fitting.options.detection_settings`);
3. :mod:`.refine` — the optional refinement on the pixels (:func:`~.refine.refine_fit`);
4. :mod:`.outputs` — mesh, report, texture, overlays: every output checked before any work
   (:func:`~.outputs.check_output_paths`), written atomically, all or nothing
   (:func:`~.outputs.write_outputs`);
5. :mod:`.batch` — :func:`~.batch.fit_item`, the work function of ``morphable fit-batch``
   (:func:`morphable.batch.run_batch`);
6. :mod:`.track` — a video's track (:func:`morphable.tracking.track_video`, also
   ``morphable.track_video``) written to files (:func:`~.track.write_track`), and every
   person's (:func:`morphable.tracking.track_footage`): :func:`~.track.write_footage`.

Every problem with an input is an :class:`~morphable.errors.InputError` naming the file.
Units: mm and degrees; image points in pixels, 0-based, x right, y down.
"""
from .batch import fit_item
from .fit import ImageFit, fit_images, one_landmark_set
from .inputs import (MAX_DETECT_MEGAPIXELS, OUTSIDE_MARGIN, Picture, check_landmarks, detect_points,
                     pictures, read_landmark_file)
from .outputs import check_output_paths, write_outputs
from .refine import refine_fit
from .track import check_track_folder, keep_person, write_footage, write_track

__all__ = ["fit_images", "ImageFit", "Picture", "pictures", "read_landmark_file", "check_landmarks",
           "detect_points", "one_landmark_set", "refine_fit", "check_output_paths", "write_outputs",
           "fit_item", "write_track", "write_footage", "keep_person", "check_track_folder", "MAX_DETECT_MEGAPIXELS", "OUTSIDE_MARGIN"]
