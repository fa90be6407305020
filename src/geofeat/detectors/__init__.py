"""Keypoint detectors: OpenCV SIFT (`geofeat.keypoints.detect`, the protocol's keypoints) and GeoKey
(`geokey`, the learned deformation-aware detector). `geofeat.detect(frame, n, detector=...)` picks one."""
