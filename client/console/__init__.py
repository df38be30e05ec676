"""The command console: a live map of every responder, alarms and operator fixes in a browser.

:func:`client.console.server.start_console` serves it from a zenoh session (``firetrack serve``
starts it beside the service; ``firetrack console --connect ...`` runs it alone). The page
(``static/``) is hand-written HTML, CSS and JavaScript with no build step and nothing fetched
from the internet, so it works on a laptop at the incident with no network but the router's.

Modules: :mod:`~client.console.server` (HTTP + WebSocket, start/close),
:mod:`~client.console.live` (latest pose and status per responder, batched for the page),
:mod:`~client.console.plans` (floor-plan images for the browser and their pixel <-> ENU maps),
:mod:`~client.console.screenshot` (the README's picture).
"""
