"""Camera back-ends behind :class:`inspect_pipe.capture.FrameSource`: ``v4l2`` (OpenCV), ``ids``
(IDS peak, uEye fallback), ``sim`` (the simulated vehicle's camera), ``replay`` (sweep, image
folder, video file). Vendor SDKs are imported only when their source is opened."""
