"""The rules the CPU kernels use, compiled for the CPU (:func:`flocking.rules.compile`).

>>> wrap(-0.5, 4.0)
3.5
"""

from ..rules import compile as _compile

_R = _compile("cpu")
minimum_image, wrap, update_2d, update_3d = _R.minimum_image, _R.wrap, _R.update_2d, _R.update_3d
