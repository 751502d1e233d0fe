"""`nerfaug view RUN`: a capture session in the browser (viser): its cameras, the candidate views
by score, the proposals, the hemisphere and the NeRF's box, and a live render of its NeRF; it follows
the session as it trains, proposes and adds, and writes nothing into the run folder.

`snapshot` reads the run folder (no viser), `scene` draws it, `render` renders the NeRF at the
browser's camera, `app` serves them (`Viewer`). viser is the optional extra `viewer`."""
