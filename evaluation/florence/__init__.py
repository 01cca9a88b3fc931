"""The Florence evaluation protocol on any scan: reconstruct from video frames, compare.

For each condition a video of the scan is made (synthetic: :mod:`evaluation.videos`; or
real frames in a Florence-layout folder), ``--frames`` frames are sampled uniformly, each
method reconstructs the face from their landmarks, the per-frame meshes are averaged, and the
average is compared with the scan (:func:`morphable.metrics.compare_to_scan`: landmark
similarity, crop of 95 mm around the nose tip, ICP, point-to-plane error per vertex).

Command::

    python -m evaluation.florence --scan ../shared/data/scans/james/james.obj \\
        --scan-landmarks ../shared/data/scans/james/james.ljson \\
        --methods ours eos mean-face --report reports/florence_james.json

prints a table (method x condition, mean ± std of the point-to-plane error in mm, seconds per
frame) and writes the JSON report plus the per-vertex errors (``.npz`` beside the report).
One synthetic video per condition is one draw of a head-pose trajectory and of landmark noise;
``--n-videos 5`` runs five draws (seeds ``--seed`` to ``--seed + 4``) and gives the mean and
standard deviation over them. Methods ``surface-fit`` and ``landmarks-3d`` are no
reconstructions from the frames but the model fitted to the scan itself: to its surface (the
error no method with that model can go below), or to its own 3D landmarks (what the
landmarks say about the face's shape under the model, without images).

A validation set that is not a real scan (for choosing settings without touching the held-out
scans): ``--synthetic-scan ict --n-scans 8`` samples subjects from another model
(:func:`evaluation.scans.model_scan`, its own landmark vertices as the scan landmarks) and
reports, per method and condition, the mean over the subjects::

    python -m evaluation.florence --synthetic-scan ict --n-scans 8 \
        --methods ours ours-independent eos mean-face --report reports/florence_ict.json

or subjects of the fitted model itself with a landmark definition error added
(``--synthetic-scan sfm --definition-noise 2.5``); ``--expression-std`` gives them
expressions; ``--n-videos 5`` draws each subject's videos five times (a subject's value is
then its mean over the draws; ``draw_std_mm`` in the report, the spread over draws). With
``--detect`` their frames are rendered and a detector finds the landmarks
(``--landmark-detector``, ``--face-detector``; default the face mesh when installed, else dlib);
``--appearance PHOTO ...`` dresses the subjects in the colours of photos of faces
(:func:`evaluation.scans.photo_colors`), without which a detector sees clay.

Modules: :mod:`~evaluation.florence.methods` (one class per method and their registry
:data:`~evaluation.florence.methods.METHODS`: adding a method is one class),
:mod:`~evaluation.florence.protocol` (the runs, their comparison with the scan, the table, the
error maps) and :mod:`~evaluation.florence.cli` (the command).
"""
