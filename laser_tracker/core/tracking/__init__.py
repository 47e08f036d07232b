"""The hypothesis tracker's roles (paper Sec. 7-9), one module each.

``core.hypotheses.HypothesisTracker.update`` runs them per frame, in this order:

==================  ================================================  =====================
module              role                                              paper
==================  ================================================  =====================
``frame``           the frame's measurements (finite, in range, not   (input)
                    the robot's body) and the scanner's motion
``association``     person detections as measurements; Eq. 2,         Sec. 7-8, Eq. 2, 3
                    gating and splitting; Eq. 3 and the Kalman
                    update; the wall penalty
``sustaining``      unsupported hypotheses: held on a scan segment,   Sec. 8 (coasting)
                    else coasting
``initiation``      new hypotheses from new blobs and from people     Sec. 7
``identity``        ids through splits, merges (duplicates) and       Sec. 8 (merging)
                    short losses (resume)
``deletion``        removal below ``remove_below``; the bound         Sec. 8
``confirmation``    the paper's m samples and the further rules,      Sec. 8
                    each a small function
``visibility``      coasting tracks whose place the scan sees empty   (beyond the paper)
                    are not reported
==================  ================================================  =====================

The state of all hypotheses is one numpy structured array (``state.Hypotheses``); the
Kalman filters are ``core.kalman.TrackFilter``. Every role reads the ``hypotheses.*``
parameters (``core.hypotheses.HypothesisConfig``).
"""
