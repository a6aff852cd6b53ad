"""``headless_env``: SDL's dummy drivers under both SDL2's and SDL3's variable names."""

from __future__ import annotations

import os

from game.display import has_display, headless_env

NAMES = {
    "video": ("SDL_VIDEODRIVER", "SDL_VIDEO_DRIVER"),  # SDL2, SDL3
    "audio": ("SDL_AUDIODRIVER", "SDL_AUDIO_DRIVER"),
}


def test_headless_env_sets_sdl2_and_sdl3_video_and_audio_to_dummy():
    given = {
        "DISPLAY": ":0",
        "HOME": "/home/x",
        "SDL_VIDEODRIVER": "x11",
        "SDL_AUDIO_DRIVER": "pulseaudio",
    }
    env = headless_env(given)
    for kind, names in NAMES.items():
        for name in names:
            assert env[name] == "dummy", (kind, name)
    assert env["HOME"] == "/home/x" and env["DISPLAY"] == ":0"  # the rest is kept
    assert given["SDL_VIDEODRIVER"] == "x11"  # a copy: the caller's dict is untouched
    assert not has_display(env)


def test_headless_env_defaults_to_a_copy_of_os_environ(monkeypatch):
    for names in NAMES.values():
        for name in names:
            monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOLO_GAME_TEST_MARK", "kept")
    env = headless_env()
    assert env["HOLO_GAME_TEST_MARK"] == "kept"
    assert all(env[n] == "dummy" for names in NAMES.values() for n in names)
    assert not any(n in os.environ for names in NAMES.values() for n in names)
