"""The navigation and lap envs' ``rgb_array`` picture, and SB3's VecVideoRecorder and rl_zoo3's record_video on it."""

import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecVideoRecorder

import sb3_mpail.envs  # noqa: F401  (registers the environments)
from sb3_mpail.demos import shipped_demos
from sb3_mpail.envs.lap import lap_driver
from sb3_mpail.envs.navigation import (
    CAR_COLOUR,
    GOAL_COLOUR,
    PATH_COLOUR,
    RENDER_SIZE,
    TRAIL_COLOUR,
    NavigationEnv,
)

NAVIGATION_ID = "sb3_mpail/Navigation-v0"
LAP_ID = "sb3_mpail/NavigationLap-v0"


def pixels_of(frame: np.ndarray, colour) -> np.ndarray:
    """:return: ``(n, 2)`` (row, column) of the pixels of exactly this colour"""
    return np.argwhere(np.all(frame == np.array(colour, dtype=np.uint8), axis=-1))


def read_video(path: Path) -> np.ndarray:
    """:return: the video's frames, ``(n, height, width, 3)``, decoded by moviepy (the ``video`` extra)"""
    from moviepy.video.io.VideoFileClip import VideoFileClip

    clip = VideoFileClip(str(path))
    try:
        return np.stack(list(clip.iter_frames()))
    finally:
        clip.close()


@pytest.mark.parametrize("env_id", [NAVIGATION_ID, LAP_ID])
def test_rgb_array_frame_is_a_square_uint8_picture_and_none_without_render_mode(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    assert "rgb_array" in env.metadata["render_modes"] and env.metadata["render_fps"] == 10
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (RENDER_SIZE, RENDER_SIZE, 3) and frame.dtype == np.uint8
    assert len(pixels_of(frame, CAR_COLOUR)) > 50  # the car is at least 16 x 9 pixels, its front another colour
    quiet = gym.make(env_id).unwrapped
    quiet.reset(seed=0)
    assert quiet.render() is None
    with pytest.raises(ValueError, match="render_mode"):
        NavigationEnv(render_mode="human")


def test_the_car_s_pixels_move_as_the_car_drives():
    env = NavigationEnv(render_mode="rgb_array")
    observation, _ = env.reset(seed=0)
    before = pixels_of(env.render(), CAR_COLOUR).mean(axis=0)
    view = env._view
    for _ in range(10):
        moved, *_ = env.step(np.array([0.6, 0.5], dtype=np.float32))  # forward, turning left
    frame = env.render()
    assert env._view == view  # the car stayed in the frame, so the frame did not change
    after = pixels_of(frame, CAR_COLOUR).mean(axis=0)
    scale = view[2]  # pixels per metre; rows grow downwards, y upwards
    expected = np.array([-(moved[1] - observation[1]), moved[0] - observation[0]]) * scale
    assert np.linalg.norm(expected) > 20  # a real move, several car lengths on the picture
    np.testing.assert_allclose(after - before, expected, atol=3.0)
    assert len(pixels_of(frame, TRAIL_COLOUR)) > 10  # where it drove


def test_the_picture_shows_the_goal_and_the_reference_paths():
    demos = [trajectory.obs for trajectory in shipped_demos("navigation_circling", 4)]
    navigation = NavigationEnv(render_mode="rgb_array", reference_paths=[demo[:, :2] for demo in demos])
    navigation.reset(seed=0)
    frame = navigation.render()
    assert len(pixels_of(frame, GOAL_COLOUR)) > 50 and len(pixels_of(frame, PATH_COLOUR)) > 500
    # the goal (10, 10) is up and to the right of the car near the origin
    goal, car = pixels_of(frame, GOAL_COLOUR).mean(axis=0), pixels_of(frame, CAR_COLOUR).mean(axis=0)
    assert goal[0] < car[0] - 100 and goal[1] > car[1] + 100
    # the lap draws its track (a circle through the car's start) and no goal
    lap = gym.make(LAP_ID, render_mode="rgb_array")
    lap.reset(seed=0)
    frame = lap.render()
    track = pixels_of(frame, PATH_COLOUR)
    assert len(pixels_of(frame, GOAL_COLOUR)) == 0 and len(track) > 500
    assert np.ptp(track[:, 0]) > 0.5 * RENDER_SIZE and np.ptp(track[:, 1]) > 0.5 * RENDER_SIZE


def test_the_frame_widens_to_keep_a_car_that_leaves_it():
    env = NavigationEnv(render_mode="rgb_array")
    env.reset(seed=0)
    env.render()
    left = env._view[0]
    for _ in range(30):
        observation, *_ = env.step(np.array([-1.0, 0.0], dtype=np.float32))  # reverses away from the goal, out of the frame
    frame = env.render()
    assert observation[0] < left and env._view[0] < observation[0]
    assert len(pixels_of(frame, CAR_COLOUR)) > 50


def test_stepping_without_render_mode_records_nothing_to_draw():
    env = NavigationEnv()
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.ones(2, dtype=np.float32))
    assert env._trail == []


@pytest.mark.parametrize("env_id", [NAVIGATION_ID, LAP_ID])
def test_vec_video_recorder_writes_a_video_of_the_car(tmp_path, env_id):
    pytest.importorskip("moviepy", reason="VecVideoRecorder writes through moviepy (the video extra)")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # make_vec_env asks for render_mode="rgb_array": no warning that it is missing
        venv = make_vec_env(env_id, n_envs=1, seed=0)
    recorder = VecVideoRecorder(venv, str(tmp_path), record_video_trigger=lambda step: step == 0, video_length=20)
    observations = recorder.reset()
    for _ in range(25):
        observations, *_ = recorder.step(np.stack([lap_driver(observation) for observation in observations]))
    recorder.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1
    frames = read_video(videos[0])
    assert frames.shape[1:] == (RENDER_SIZE, RENDER_SIZE, 3) and len(frames) >= 20
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).max() > 100  # the car moved between them


def test_zoo_record_video_films_a_trained_planner(tmp_path):
    pytest.importorskip("rl_zoo3", reason="needs the zoo extra")
    pytest.importorskip("moviepy", reason="rl_zoo3's record_video writes through moviepy (the video extra)")
    config = tmp_path / "mpail.yml"
    config.write_text(
        f"{NAVIGATION_ID}:\n  n_timesteps: 32\n  n_envs: 2\n  policy: 'MlpMPPI'\n"
        "  demos: navigation_circling_4\n  n_steps: 16\n"
        '  policy_kwargs: "dict(n_samples=8, horizon=3, n_iterations=1)"\n'
    )
    logs = tmp_path / "logs"

    def zoo(*arguments: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "sb3_mpail.zoo", *arguments], capture_output=True, text=True, timeout=300)

    trained = zoo("train", "--algo", "mpail", "--env", NAVIGATION_ID, "-conf", str(config), "-f", str(logs), "--seed", "0")
    assert trained.returncode == 0, trained.stderr[-3000:]
    recorded = zoo("record_video", "--algo", "mpail", "--env", NAVIGATION_ID, "-f", str(logs), "--exp-id", "1", "-n", "15")
    assert recorded.returncode == 0, recorded.stderr[-3000:]
    videos = list((logs / "mpail").glob("*/videos/*.mp4"))
    assert len(videos) == 1
    assert read_video(videos[0]).shape[1:] == (RENDER_SIZE, RENDER_SIZE, 3)
