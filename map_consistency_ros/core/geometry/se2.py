"""Planar rigid transforms on pose arrays of shape (..., 3) holding (x, y, theta)."""
import numpy as np

# A 2D laser map, indoors or outdoors, spans kilometres: a coordinate (or a displacement, or a
# laser reading) beyond 100 km is a corrupt number, not a place. Every input is held to it
# (io/limits.py DISTANCE, core.backend MAX_POSE_EXTENT, the node's max_pose_extent default).
MAX_EXTENT = 1e5  # m


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Map angles to [-pi, pi).

    Parameters
    ----------
    angle: angles in radians, a scalar or an array of any shape.

    Returns
    -------
    The angles shifted by multiples of 2 pi into [-pi, pi), of `angle`'s shape.
    """
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def yaw_from_quaternion(x, y, z, w):
    """Rotation about z of (possibly unnormalised) quaternions, scalars or arrays.

    Parameters
    ----------
    x, y, z, w: the quaternions' components, scalars or arrays of one broadcastable shape.

    Returns
    -------
    The yaw in radians, in [-pi, pi]: a float for scalar components, else an array. NaN where a
    quaternion has no heading: a non-finite component (arctan2 would turn an infinite one into
    a plausible angle) or a zero norm.
    """
    x, y, z, w = (np.asarray(v, dtype=np.float64) for v in (x, y, z, w))
    # w^2 + x^2 - y^2 - z^2 rather than 1 - 2 (y^2 + z^2): the same for unit quaternions,
    # and independent of the norm for the others.
    with np.errstate(invalid='ignore', over='ignore'):
        yaw = np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)
        usable = (np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & np.isfinite(w)
                  & ((x * x + y * y + z * z + w * w) > 0.0))
    yaw = np.where(usable, yaw, np.nan)
    return float(yaw) if yaw.ndim == 0 else yaw


def quaternion_from_yaw(yaw: float) -> tuple[float, float]:
    """The unit quaternion of a rotation about z.

    Parameters
    ----------
    yaw: the rotation in radians.

    Returns
    -------
    Its (z, w) components (x = y = 0).
    """
    return float(np.sin(0.5 * yaw)), float(np.cos(0.5 * yaw))


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (+) b: the pose b, given relative to a, expressed in a's parent frame.

    Parameters
    ----------
    a: (..., 3) poses (x, y, theta) in their parent frame, metres and radians.
    b: (..., 3) poses relative to `a`, broadcastable against it.

    Returns
    -------
    (..., 3) the composed poses, theta wrapped to [-pi, pi).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cos_a, sin_a = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + cos_a * b[..., 0] - sin_a * b[..., 1]
    y = a[..., 1] + sin_a * b[..., 0] + cos_a * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: np.ndarray) -> np.ndarray:
    """The pose that undoes a: compose(a, inverse(a)) is the identity.

    Parameters
    ----------
    a: (..., 3) poses (x, y, theta).

    Returns
    -------
    (..., 3) their inverses, theta wrapped to [-pi, pi).
    """
    a = np.asarray(a, dtype=np.float64)
    cos_a, sin_a = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -cos_a * a[..., 0] - sin_a * a[..., 1]
    y = sin_a * a[..., 0] - cos_a * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 (+) b: the pose b expressed in the frame of a.

    Parameters
    ----------
    a: (..., 3) the poses whose frames to express `b` in.
    b: (..., 3) poses in the same parent frame as `a`, broadcastable against it.

    Returns
    -------
    (..., 3) `b` relative to `a`, theta wrapped to [-pi, pi).
    """
    return compose(inverse(a), b)


def chain(start: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses reached from `start` by composing the relative steps in order.

    Parameters
    ----------
    start: (3,) the first pose.
    steps: (M, 3) relative poses, each given in the frame of the pose before it.

    Returns
    -------
    (M + 1, 3) the poses, the first being `start`.
    """
    poses = np.empty((len(steps) + 1, 3))
    poses[0] = start
    for index, step in enumerate(steps):
        poses[index + 1] = compose(poses[index], step)
    return poses
