"""Tracking faces through videos.

- :mod:`.single` — one face through a video: :func:`track_video` (one identity, a pose and an
  expression per frame; also ``morphable.track_video``), its steps (:func:`fit_frames`,
  :func:`carried_box`, :func:`smooth_trajectories`, ...) and :func:`write_track_glb`;
- :mod:`.footage` — every face of a video, shot by shot, joined into people:
  :func:`track_footage` (``morphable track``; also ``morphable.track_footage``), its
  :class:`FootageResult` and steps (:func:`associate`, :func:`join_tracks`).

Units: angles in degrees, translations in mm, image points in pixels (0-based, x right, y down).
"""
from .footage import (DESCRIPTOR_EVERY_S, IDENTITY_FRAMES, MATCH_IOU, MAX_DESCRIPTORS, QUICK_S, REDETECT_S, STATUSES,
                      FootageResult, TrackInfo, associate, join_tracks, track_footage)
from .single import (CHUNK_BYTES, DEFAULT_IDENTITY, DEFAULT_SMOOTHING_HZ, IDENTITY_MODES, LOST_RMSE_FRACTION,
                     TrackResult, carried_box, chunk_frames, fit_frames, fixed_identity_model,
                     smooth_trajectories, solve_prior, track_video, write_track_glb)

__all__ = ["TrackResult", "track_video", "write_track_glb", "fixed_identity_model", "carried_box",
           "fit_frames", "chunk_frames", "smooth_trajectories", "solve_prior", "DEFAULT_SMOOTHING_HZ",
           "LOST_RMSE_FRACTION", "CHUNK_BYTES", "IDENTITY_MODES", "DEFAULT_IDENTITY",
           "FootageResult", "TrackInfo", "track_footage", "associate", "join_tracks", "REDETECT_S",
           "DESCRIPTOR_EVERY_S", "MAX_DESCRIPTORS", "IDENTITY_FRAMES", "MATCH_IOU", "STATUSES", "QUICK_S"]
