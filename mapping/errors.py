"""Error root of the mapping package."""


class MappingError(Exception):
    """Root of every error the mapping package raises on purpose."""


class PointCloudFormatError(MappingError, ValueError):
    """A point-cloud file or message is malformed, truncated or of an unsupported layout."""


class GridSpecError(MappingError, ValueError):
    """A grid specification has an invalid field."""
