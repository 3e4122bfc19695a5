"""The robot's side, NumPy only (no JAX): the fitted frames as plain numbers
(:class:`Frames`), the hand command from them (:class:`Predictor`), and their exports (URDF,
ROS 2, OpenCV, YAML, JSON, a NumPy module). A robot PC needs nothing above this folder."""
