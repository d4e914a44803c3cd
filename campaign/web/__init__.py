"""The operator's page: a live campaign on a tablet beside the cell (issue 22). A subscriber of the engine's
documents (hub.py), its view folded from the session's events (state.py), served by Starlette on uvicorn with
server-sent events (app.py, server.py), the page itself plain HTML, CSS and JS in static/ (no build, no CDN)."""
