"""rheo_ros: physical parameters of rheological objects from tactile and marker data.

Layers: ``models`` (rheological elements, effects), ``fe`` (the paper's FE model),
``identification`` (the paper's equations, whole-record refinement), ``diagnosis``
(compare, diagnose, analyze), ``reports``, ``bench`` and ``cli``. The core imports no
ROS.

``rheo_ros.analyze(bag, effects=[...])`` is the model-discovery loop in one call
(``rheo_ros.app.analyze.analyze``).
"""

from typing import Any

__version__ = "0.1.0"


def analyze(*args: Any, **kwargs: Any) -> Any:
    """``rheo_ros.app.analyze.analyze``: imported on first use (numpy, scipy, the FE)."""
    from rheo_ros.app.analyze import analyze as run

    return run(*args, **kwargs)
