"""rheo_ros: physical parameters of rheological objects from tactile and marker data.

Layers: ``models`` (rheological elements, effects), ``fe`` (the paper's FE model),
``identification`` (the paper's equations, whole-record refinement), ``bench`` and
``cli``. The core imports no ROS.
"""

__version__ = "0.1.0"
