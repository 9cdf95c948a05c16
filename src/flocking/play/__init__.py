"""``flocking play``: the engine on a local web server, drawn live in the browser.

:mod:`~flocking.play.session` holds one simulation per browser tab, checks every control
message and encodes frames (it needs only NumPy); :mod:`~flocking.play.server` is the
Starlette app around it (the optional ``[play]`` extra). The page lives in ``static/``.
"""
