"""The camera service: a V4L2 camera, a video file or an image folder → ``camera/image``.

Pure parts (no I/O): ``calibration`` (ROS camera_info and OpenCV FileStorage YAML), ``undistort``
(the remap onto the pinhole model), ``latest`` (the
one-frame slot and the capture stamps). ``capture`` holds the sources and the capture thread
(PyAV), ``node`` the thin Zenoh wrapper.
"""
