"""Error root of the mapping package."""


class MappingError(Exception):
    """Root of every error the mapping package raises on purpose."""


class PointCloudFormatError(MappingError, ValueError):
    """A point-cloud file or message is malformed, truncated or of an unsupported layout."""


class GridSpecError(MappingError, ValueError):
    """A grid specification has an invalid field."""


class SonarModelError(MappingError, ValueError):
    """A sonar reading or a sonar-model parameter is out of its domain (negative range, bad ppc, ...)."""


class PointsError(MappingError, ValueError):
    """An in-memory point array has the wrong shape or dtype (expected (N, 3) or (H, W, 3) reals)."""


class BagTopicError(MappingError, LookupError):
    """A bag has no usable point-cloud topic, or the requested topic is absent or of another type."""
