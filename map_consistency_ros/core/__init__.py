"""The science: pure numpy / scipy / numba, no ROS and no file formats. Sub-packages by
concern, each with a public face (its __init__ and __all__), imports pointing down only:
geometry <- consistency (the paper's test) <- verdict; backend and live on top.
parameters.py (the settings' field metadata) is shared by all; configuration.py holds one
settings group of each, the configuration built once and passed down."""
