"""The face data engine: labelled faces for training networks.

- :mod:`.points` — the 546-point set every landmark pack is labelled in (and the landmark
  network predicts) and its face framing;
- :mod:`.renders` — random 3DMM faces rendered with exact labels (procedural albedo, SH light),
  the GAR's and the auxiliary networks' synthetic data;
- :mod:`.synthetic` — synthetic faces wearing real photo textures under varied light, with
  backgrounds, occluders and degradations; :mod:`.build_synthetic` packs them;
- :mod:`.annotations` — real photos' sparse annotations as rows of the point set;
  :mod:`.build_annotated` and :mod:`.build_profiled` pack them (the latter turned to new poses);
- :mod:`.shards` — resumable packs of shards; :mod:`.packs` — reading, drawing and compacting
  a landmark pack.
"""
