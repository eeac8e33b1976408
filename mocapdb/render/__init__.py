"""Pictures of results (``mocapdb render``): re-projected skeletons over the input, a 3D view,
contact sheets and the stereo camera plot. Imports only :mod:`mocapdb.core` (and OpenCV, tqdm).

``draw``: projection and OpenCV drawing; ``results``: reading result streams, ``cameras.json`` and
the 2D input; ``video``: the frame loop, :func:`~mocapdb.render.video.contact_sheet` and
:func:`~mocapdb.render.video.render_stereo_plot`.
"""
