"""Multi-touch input -> hand pose (Chung et al., Quadratic Encoding for Hand Pose
Reconstruction from Multi-Touch Input).

* :mod:`~hand_capture.touch.frame`: :class:`TouchFrame`, the touches at one instant.
* :mod:`~hand_capture.touch.tuio`, :mod:`~hand_capture.touch.evdev_mt`: sources (TUIO 1.1
  over OSC/UDP, Linux multi-touch protocol B).
* :mod:`~hand_capture.touch.encoding`: the input vector u and the linear / quadratic / cubic
  encodings (eq. 1-3).
* :mod:`~hand_capture.touch.labelling`: finger labelling by nearest training neighbour and a
  layout prior.
* :mod:`~hand_capture.touch.encoder`: frames -> poses (the encoder node's core).
* :mod:`~hand_capture.touch.datagen`, :mod:`~hand_capture.touch.train`: training data from the
  hand model, the shipped coefficient file ``data/touch/touch_model.npz``.
* :mod:`~hand_capture.touch.pcaik`: the PCA-IK baseline (sec. 3).
* :mod:`~hand_capture.touch.heldout`: the held-out evaluation family (benchmark only; training
  never imports it).
"""
