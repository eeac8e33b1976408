"""A take's world: the floor, the camera's height and tilt, and every person's size (data_specs/world.md).

One module per kind of evidence, one that fuses them:

* :mod:`~mocapdb.runtime.world.fuse`: the posterior over the camera's pitch, roll and height and each
  track's kind (on the floor, elevated, unreliable); people placed in that world;
* :mod:`~mocapdb.runtime.world.tilt`: the camera's prior and the spread of the posterior;
* :mod:`~mocapdb.runtime.world.detector_prior`: the detector's 3D landmarks, the bodies' up;
* :mod:`~mocapdb.runtime.world.image_vertical`: the image's vertical through each person's support;
* :mod:`~mocapdb.runtime.world.contact_floor`: the floor under the planted ankles;
* :mod:`~mocapdb.runtime.world.stature`: the stature prior and its likelihood;
* :mod:`~mocapdb.runtime.world.body_size`: a person's size and bone proportions;
* :mod:`~mocapdb.runtime.world.subject`: which track is the take's subject, ``--people``;
* :mod:`~mocapdb.runtime.world.summary`: the summary's lines and ``world.json``.
"""
