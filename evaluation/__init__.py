"""Evaluation of morphable against scans, peers and run time (not imported by ``morphable``)."""
