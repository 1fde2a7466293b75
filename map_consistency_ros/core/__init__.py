"""The science: pure numpy / scipy / numba, no ROS and no file formats."""
