"""``mocapdb view`` and ``mocapdb live --view``: a web page on 127.0.0.1 that shows a take or a live stream.

The server (:mod:`mocapdb.view.server`, the standard library's ``http.server``) sends the page
(``static/index.html``, ``static/viewer.js``; three.js vendored in ``vendor/three/``: nothing is
fetched at run time) and JSON: a recorded take's frames (:mod:`mocapdb.view.take`: what
``mocapdb render`` draws, each track's joints in the files' frame and re-projected through the
take's camera) or a live stream's, pushed as server-sent events (:mod:`mocapdb.view.live`).
Contract: ``data_specs/viewer.md``; guide: ``docs/guide_view.md``.
"""
