"""docs/images/motion-from-video.jpg: the body's motion followed through a real video
(`tryon.perceive.motion_from_video.read_video_motion`), drawn by `motion_picture`: each
frame with its keypoints, beside the fitted body seen from the camera's side.

    .venv/bin/python scripts/plot-motion-from-video.py VIDEO HEIGHT_CM WEIGHT_KG GENDER [START_S END_S]

The docs' picture: Sports2D's demo (BSD-3-Clause; see scripts/plot-garment-mask.py for how
to get it), 165 cm, 58 kg, female, 2.7-6.7 s.
"""

import sys

from PIL import Image

from tryon.body.fit import Measurements, fit_body
from tryon.perceive.motion_from_video import motion_picture, read_video_motion


def main() -> None:
    path, height, weight, gender = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
    start, end = (float(sys.argv[5]), float(sys.argv[6])) if len(sys.argv) > 6 else (0.0, None)
    shape = fit_body(Measurements(height_cm=height, weight_kg=weight, gender=gender)).shape
    vm = read_video_motion(path, shape, fps=15.0, start_s=start, end_s=end)
    r = vm.report()
    print(f"{r['followed_frames']} of {r['frames']} frames followed ({r['misread_frames']} misread); segments "
          f"{r['mean_angle_deg']:.1f} deg from the landmarks on average; {r['speed_m_s']:.2f} m/s")
    Image.fromarray(motion_picture(vm)).save("docs/images/motion-from-video.jpg", quality=88)


if __name__ == "__main__":
    main()
