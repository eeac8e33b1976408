"""Pictures of results (``mocapdb render``): re-projected skeletons over the input, a 3D view,
contact sheets and the stereo camera plot. Imports only :mod:`mocapdb.core` (and OpenCV, tqdm).

``draw``: projection and OpenCV drawing; ``results``: reading result streams, ``cameras.json`` and
the 2D input; ``tracks``: the track files drawn; ``frame_layout``: one output frame's layout and
panels; ``video``: the frame loop; ``video_io``: video frames read, PNG and MP4 files written;
``contact_sheet``: :func:`~mocapdb.render.contact_sheet.contact_sheet`; ``stereo_plot``:
:func:`~mocapdb.render.stereo_plot.render_stereo_plot`.
"""
