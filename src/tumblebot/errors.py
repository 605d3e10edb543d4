"""The root of tumblebot's exception hierarchy.

Every error that bad outside input can cause (a CLI argument, a config file, a design
outside the bounds, a policy file) derives from :class:`TumblebotError`, so the CLI can
print it as one line and exit non-zero instead of showing a traceback.
"""


class TumblebotError(Exception):
    """Base class of every error tumblebot raises on purpose."""
