"""The blind aid's sound: synthesis, the player's timeline, WAV/aplay/null sinks, speech."""

from __future__ import annotations

import io
import math
import os
import shutil
import sys
import wave
from pathlib import Path

import numpy as np
import pytest

from edge.errors import HardwareError
from edge.modes.blindaid import sound as audio
from edge.modes.blindaid.logic import BEEP, BLIND, SILENCE, TONE, BlindAid, BlindAidConfig, Cue
from edge.modes.blindaid.sound import (
    WARBLE_HZ,
    WARBLE_STEP_S,
    AplaySink,
    CuePlayer,
    NullSink,
    Synth,
    WavSink,
    open_sink,
    parse_wav_bytes,
    read_wav,
    resample_linear,
    speak_to_frames,
)
from edge.ranging import OK, ZoneResult

SR = 22050
CFG = BlindAidConfig()
A = CFG.volume * 32767  # peak of a mono sound before panning


def beep(interval: float = 0.25, pitch: float = 1000.0, pan: float = 0.0) -> Cue:
    return Cue(BEEP, bearing_deg=-pan * 30, range_m=1.0, zone=3, interval_s=interval, pitch_hz=pitch, pan=pan)


def peak_hz(x: np.ndarray, sr: int = SR) -> float:
    spec = np.abs(np.fft.rfft(x.astype(np.float64) * np.hanning(len(x))))
    k = int(np.argmax(spec))
    if 0 < k < len(spec) - 1:  # parabolic interpolation of the peak
        a, b, c = np.log(spec[k - 1:k + 2] + 1e-12)
        k = k + 0.5 * (a - c) / (a - 2 * b + c)
    return k * sr / len(x)


def onsets_s(x: np.ndarray, sr: int = SR, threshold: float = 0.1) -> np.ndarray:
    """Times where the 1 ms peak envelope first rises above threshold × its maximum."""
    block = sr // 1000
    env = np.abs(x[: len(x) // block * block].astype(np.float64)).reshape(-1, block).max(axis=1)
    on = env > threshold * env.max()
    rises = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    if on[0]:
        rises = np.concatenate(([0], rises))
    return rises * block / sr


def max_jump(x: np.ndarray) -> float:
    return float(np.abs(np.diff(x.astype(np.float64), axis=0)).max())


# --- synthesis ---------------------------------------------------------------------------------


def test_render_shape_dtype_and_silence() -> None:
    s = Synth(SR)
    out = s.render(Cue(), 0.0, 0.5)
    assert out.shape == (SR // 2, 2) and out.dtype == np.int16
    assert not out.any()


def test_beep_pitch_is_the_cues() -> None:
    cue = BlindAid(BlindAidConfig(speak_new=False)).update(
        ZoneResult(3, 0.0, 0.0, OK, range_m=1.3), 0.0)
    assert cue is not None and cue.sound == BEEP and cue.pitch_hz is not None
    out = Synth.from_config(CFG).render(cue, 0.0, 1.0)
    assert peak_hz(out[:, 0]) == pytest.approx(cue.pitch_hz, rel=0.02)
    tone = Synth(SR).render(Cue(TONE, range_m=0.3, pitch_hz=1600.0, pan=0.0), 0.0, 0.5)
    assert peak_hz(tone[:, 1]) == pytest.approx(1600.0, rel=0.02)


@pytest.mark.parametrize("interval", [0.08, 0.15, 0.4])
def test_beeps_at_the_cues_interval_and_length(interval: float) -> None:
    out = Synth(SR, beep_s=0.05, ramp_s=0.005).render(beep(interval, 800.0), 0.0, 2.0)
    t = onsets_s(out[:, 0])
    assert t[0] <= 0.002  # the first beep starts at once
    assert len(t) == int(np.ceil(2.0 / interval - 1e-9))
    assert np.diff(t) == pytest.approx(np.full(len(t) - 1, interval), abs=0.0015)
    # Each beep lasts beep_s (ramps included): the envelope is zero between them.
    first = np.flatnonzero(out[: int(interval * SR), 0])
    assert (first[-1] - first[0]) / SR == pytest.approx(0.05, abs=0.001)


def test_beep_ramps_are_smooth() -> None:
    out = Synth(SR, volume=1.0).render(beep(0.2, 200.0), 0.0, 0.2)[:, 0].astype(float)
    # A 200 Hz sine's own steepest step plus the raised cosine's: no step from 0 to full scale.
    bound = 32767 * np.sqrt(0.5) * (2 * np.pi * 200 / SR + np.pi / (2 * round(0.005 * SR))) + 2
    assert max_jump(out) <= bound


def test_left_panned_cue_is_louder_on_the_left() -> None:
    aid = BlindAid(BlindAidConfig(speak_new=False))
    cue = aid.update(ZoneResult(0, 30.0, 0.0, OK, range_m=1.0), 0.0)  # positive pan: left
    assert cue is not None and cue.pan == -1.0
    out = Synth(SR).render(cue, 0.0, 1.0).astype(float)
    left, right = (out**2).sum(axis=0)
    assert left > 100 * max(right, 1.0)
    half = Synth(SR).render(beep(pan=-0.5), 0.0, 1.0).astype(float)
    e = (half**2).sum(axis=0)
    assert e[0] > 3 * e[1] > 0
    centre = Synth(SR).render(beep(pan=0.0), 0.0, 1.0).astype(float)
    e = (centre**2).sum(axis=0)
    assert e[0] == pytest.approx(e[1], rel=1e-3)
    # Constant power: the total is the same wherever the sound is placed.
    assert (half**2).sum() == pytest.approx((centre**2).sum(), rel=0.01)


def test_chunks_join_into_the_same_stream() -> None:
    cue = beep(0.13, 700.0, pan=0.3)
    whole = Synth(SR).render(cue, 0.0, 1.5)
    rng = np.random.default_rng(1)
    s = Synth(SR)
    parts, n = [], 0
    while n < len(whole):
        k = int(min(rng.integers(1, 900), len(whole) - n))
        parts.append(s.render_n(cue, k))
        n += k
    chunked = np.concatenate(parts)
    assert chunked.shape == whole.shape
    assert np.abs(chunked.astype(int) - whole.astype(int)).max() <= 1
    # render(start_s, duration_s) with float times: consecutive 20 ms pieces give the same count.
    s = Synth(SR)
    pieces = [s.render(cue, i * 0.02, 0.02) for i in range(75)]
    assert sum(len(p) for p in pieces) == len(whole)


def test_no_clicks_when_cues_change_at_chunk_joins() -> None:
    cues = [Cue(), beep(0.1, 300.0, -0.5), Cue(TONE, pitch_hz=350.0, pan=0.8), beep(0.2, 250.0, 0.0),
            Cue(TONE, pitch_hz=400.0, pan=-1.0), Cue(SILENCE), beep(0.09, 380.0, 1.0)]
    rng = np.random.default_rng(7)
    s = Synth(SR, volume=1.0)
    parts, joins, n = [], [], 0
    for _ in range(120):
        k = int(rng.integers(50, 700))
        parts.append(s.render_n(cues[int(rng.integers(len(cues)))], k))
        n += k
        joins.append(n)
    out = np.concatenate(parts).astype(float)
    w = 2 * np.pi * 400.0 / SR
    bound = 32767 * (w + np.pi / (2 * s.ramp_n) + 1.0 / s.pan_glide_n) + 2
    assert max_jump(out) <= bound
    j = np.array(joins[:-1])
    assert np.abs(out[j] - out[j - 1]).max() <= bound
    assert np.abs(out).max() > 0.5 * 32767  # it did play


def test_cannot_see_is_a_low_warble_unlike_silence_beeps_and_the_tone() -> None:
    """The blind cue: loud and continuous (no gap, unlike beeps; unlike silence), centred, two
    low pitches taking turns every WARBLE_STEP_S (unlike the one high tone), without clicks."""
    blind = Cue(BLIND, reason="camera fault", pan=1.0)  # a pan given is ignored: from the centre
    out = Synth(SR, volume=1.0).render(blind, 0.0, 1.0)
    left, right = out[:, 0].astype(float), out[:, 1].astype(float)
    assert np.array_equal(left, right)
    step = round(WARBLE_STEP_S * SR)
    rms = np.sqrt(np.mean(left[: step * 8].reshape(8, step)[:, step // 8:] ** 2, axis=1))
    assert (rms > 0.25 * 32767).all()  # never a gap (a full sine, centred: 0.5 × full scale rms)
    pitches = [peak_hz(left[i * step + step // 8: (i + 1) * step]) for i in range(6)]
    assert pitches[0::2] == pytest.approx([WARBLE_HZ[0]] * 3, rel=0.03)
    assert pitches[1::2] == pytest.approx([WARBLE_HZ[1]] * 3, rel=0.03)
    assert max(WARBLE_HZ) < CFG.pitch_low_hz  # below every beep and the tone
    w = 2 * np.pi * max(WARBLE_HZ) / SR
    assert max_jump(out) <= 32767 * (w + np.pi / (2 * Synth(SR).ramp_n)) + 2  # the steps do not click
    # Beeps and the tone heard one after another with it: each unlike the warble.
    s = Synth(SR)
    for cue in (beep(0.2, 500.0), Cue(TONE, pitch_hz=1600.0), Cue()):
        s.render(blind, 0.0, 0.5)
        other = s.render(cue, 0.5, 1.0)[round(0.05 * SR):, 0].astype(float)
        if cue.sound == SILENCE:
            assert not other.any()
        else:
            assert peak_hz(other) >= CFG.pitch_low_hz
        s = Synth(SR)


def test_nearer_beep_speeds_up_at_once() -> None:
    s = Synth(SR)
    a = s.render(beep(1.0, 500.0), 0.0, 0.3)  # first beep at 0, the next due at 1.0
    b = s.render(beep(0.1, 900.0), 0.3, 0.7)  # nearer: next beep at last + 0.1 → now
    assert onsets_s(a[:, 0])[0] <= 0.002
    assert onsets_s(b[:, 0])[0] <= 0.002


# --- the player and the WAV sink ---------------------------------------------------------------


def test_player_writes_wav_of_the_timeline(tmp_path: Path) -> None:
    path = tmp_path / "run.wav"
    player = CuePlayer(Synth(SR), WavSink(path, SR), chunk_s=0.02)
    player.advance(0.49)
    player.set_cue(beep(0.25, 600.0, -1.0), 0.503)
    player.advance(1.0)
    player.advance(1.5, Cue())
    player.close(2.345)
    rate, frames = read_wav(path)
    with wave.open(str(path), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate()) == (2, 2, SR)
    assert rate == SR and frames.shape == (math.ceil(2.345 * SR), 2)  # every sample before 2.345 s
    assert not frames[: round(0.52 * SR)].any()  # silence before the cue's chunk boundary
    assert frames[round(0.52 * SR) + 100, 0] != 0 or frames[round(0.52 * SR) + 101, 0] != 0
    (t_cue, start), (t2, start2) = player.starts
    assert (t_cue, start) == (0.503, pytest.approx(0.52))
    assert 0 <= start - t_cue <= 0.02  # the chunk bounds the added latency
    assert start2 == pytest.approx(1.5)
    t = onsets_s(frames[:, 0])
    assert t == pytest.approx([0.52, 0.77, 1.02, 1.27], abs=0.0015)
    assert not frames[round(1.51 * SR):].any()  # silence after 1.5 (ramp out included)
    assert not frames[:, 1].any()  # full left


def test_player_advance_rounds_up_to_chunks_and_lead(tmp_path: Path) -> None:
    sink = NullSink(SR)
    player = CuePlayer(Synth(SR), sink, chunk_s=0.02, lead_s=0.04)
    player.advance(0.101)
    assert sink.frames == round(0.16 * SR)  # 0.101 + 0.04 → the boundary at 0.16
    assert player.position_s == pytest.approx(0.16)
    player.set_cue(beep(), 0.11)  # already written past it: starts at the next unwritten sample
    player.advance(0.2)
    assert player.starts[-1] == (0.11, pytest.approx(0.16))
    player.close()
    assert sink.closed


def test_player_mixes_speech_and_ducks_beeps() -> None:
    class Keep(NullSink):
        def __init__(self) -> None:
            super().__init__(SR)
            self.parts: list[np.ndarray] = []

        def write(self, frames: np.ndarray) -> None:
            super().write(frames)
            self.parts.append(frames)

    sink = Keep()
    player = CuePlayer(Synth(SR), sink, chunk_s=0.02)
    player.set_cue(Cue(TONE, pitch_hz=500.0, pan=0.0), 0.0)
    speech = np.full((SR // 10, 2), 3000, dtype=np.int16)
    player.say(speech, 0.3)
    player.close(1.0)
    out = np.concatenate(sink.parts).astype(float)
    before = np.abs(out[round(0.2 * SR):round(0.3 * SR), 0]).max()
    during = out[round(0.33 * SR):round(0.39 * SR), 0] - 3000
    assert np.abs(during).max() < 0.4 * before  # ducked tone under the speech
    assert out[round(0.35 * SR), 0] != 0
    assert np.abs(out[round(0.5 * SR):, 0]).max() > 0.9 * before  # back up after it


def test_wav_sink_is_atomic_and_valid_while_writing(tmp_path: Path) -> None:
    path = tmp_path / "out.wav"
    path.write_bytes(b"old")
    sink = WavSink(path, SR)
    frames = Synth(SR).render(beep(), 0.0, 0.3)
    sink.write(frames[:3000])
    sink.write(frames[3000:])
    assert path.read_bytes() == b"old"  # untouched until close
    assert sink.tmp_path.exists() and sink.tmp_path.parent == tmp_path
    with wave.open(str(sink.tmp_path), "rb") as w:  # a kill now would leave a valid partial WAV
        assert w.getnframes() == len(frames) and w.getnchannels() == 2
    sink.close()
    sink.close()  # idempotent
    assert not sink.tmp_path.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["out.wav"]
    rate, back = read_wav(path)
    assert rate == SR and np.array_equal(back, frames)
    with pytest.raises(ValueError, match="after close"):
        sink.write(frames)


def test_wav_sink_discard_and_bad_frames(tmp_path: Path) -> None:
    sink = WavSink(tmp_path / "x.wav", SR)
    with pytest.raises(ValueError, match=r"\(N, 2\) int16"):
        sink.write(np.zeros((10, 2), dtype=np.float32))
    with pytest.raises(ValueError):
        sink.write(np.zeros(10, dtype=np.int16))
    sink.discard()
    assert list(tmp_path.iterdir()) == []
    empty = WavSink(tmp_path / "e.wav", 44100)
    empty.close()
    rate, frames = read_wav(tmp_path / "e.wav")
    assert rate == 44100 and frames.shape == (0, 2)
    with pytest.raises(HardwareError, match="cannot write"):
        WavSink(tmp_path / "no" / "such" / "dir.wav", SR)


def test_open_sink_words(tmp_path: Path) -> None:
    assert isinstance(open_sink("null", SR), NullSink)
    s = open_sink(str(tmp_path / "a.wav"), SR)
    assert isinstance(s, WavSink)
    s.close()


# --- aplay ------------------------------------------------------------------------------------


def test_aplay_missing_is_one_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(HardwareError) as e:
        AplaySink(SR)
    msg = str(e.value)
    assert "aplay not found" in msg and "alsa-utils" in msg and "\n" not in msg
    with pytest.raises(HardwareError):
        open_sink("alsa", SR)


def _fake(tmp_path: Path, name: str, body: str) -> Path:
    exe = tmp_path / name
    exe.write_text(f"#!{sys.executable}\n{body}")
    exe.chmod(0o755)
    return exe


def test_aplay_sink_pipes_raw_s16le(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "played"
    _fake(tmp_path, "aplay", (
        "import sys, os\n"
        f"open({str(out) + '.args'!r}, 'w').write('\\n'.join(sys.argv[1:]))\n"
        f"open({str(out)!r}, 'wb').write(sys.stdin.buffer.read())\n"
    ))
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}")
    sink = AplaySink(SR, device="hw:1,0")
    frames = Synth(SR).render(beep(), 0.0, 0.2)
    sink.write(frames[:1000])
    sink.write(frames[1000:])
    sink.close()
    args = (tmp_path / "played.args").read_text().split("\n")
    assert args[:9] == ["-q", "-t", "raw", "-f", "S16_LE", "-c", "2", "-r", str(SR)]
    assert args[-2:] == ["-D", "hw:1,0"]
    assert out.read_bytes() == frames.astype("<i2").tobytes()


def test_aplay_that_dies_is_a_hardware_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake(tmp_path, "aplay",
          "import sys\nsys.stderr.write('aplay: main: audio open error: No such device\\n')\nsys.exit(1)\n")
    monkeypatch.setenv("PATH", str(tmp_path))
    sink = AplaySink(SR)
    sink._proc.wait()
    with pytest.raises(HardwareError, match="exit status 1.*No such device"):
        sink.write(np.zeros((100, 2), dtype=np.int16))
    sink.close()


# --- speech ------------------------------------------------------------------------------------


def test_wav_parsing_and_resampling() -> None:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes(np.arange(-800, 800, dtype="<i2").tobytes())
    rate, x = parse_wav_bytes(buf.getvalue())
    assert rate == 16000 and x.shape == (1600, 1) and x[0, 0] == -800
    y = resample_linear(x, 16000, 22050)
    assert len(y) == round(1600 * 22050 / 16000)
    assert np.all(np.diff(y[:, 0]) > 0) and y[0, 0] == -800
    with pytest.raises(ValueError):
        parse_wav_bytes(b"not a wav at all")


def test_speech_missing_returns_none_and_logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(audio, "_SPEECH_MISSING_LOGGED", False)
    with caplog.at_level("INFO", logger="edge.modes.blindaid.sound"):
        assert speak_to_frames("way clear", SR) is None
    assert "espeak-ng is not installed" in caplog.text


def test_speech_engine_gets_text_as_one_argument(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A stand-in espeak-ng: streams a 16 kHz WAV with placeholder sizes, as the real one does into a
    pipe, and records its arguments. Shell syntax in the text must arrive untouched."""
    record = tmp_path / "argv"
    _fake(tmp_path, "espeak-ng", (
        "import sys, struct\n"
        f"open({str(record)!r}, 'w').write('\\x00'.join(sys.argv[1:]))\n"
        "n = 8000\n"
        "data = b''.join(struct.pack('<h', 1000 if (i // 20) % 2 else -1000) for i in range(n))\n"
        "hdr = b'RIFF' + struct.pack('<I', 0x7ffff024) + b'WAVEfmt '\n"
        "hdr += struct.pack('<IHHIIHH', 16, 1, 1, 16000, 32000, 2, 16)\n"
        "sys.stdout.buffer.write(hdr + b'data' + struct.pack('<I', 0x7ffff000) + data)\n"
    ))
    monkeypatch.setenv("PATH", str(tmp_path))
    text = "$(touch pwned); `id` | rm -rf x && 'one' \"two\""
    frames = speak_to_frames(text, SR)
    assert frames is not None and frames.dtype == np.int16 and frames.shape == (round(8000 * SR / 16000), 2)
    assert np.array_equal(frames[:, 0], frames[:, 1])
    assert not frames.flags.writeable
    assert record.read_text().split("\x00")[-1] == text
    assert not (tmp_path / "pwned").exists()
    assert speak_to_frames("-v evil", SR) is not None  # an option-looking text stays text
    assert record.read_text().split("\x00")[-1] == " -v evil"


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (apt install espeak-ng)")
def test_real_espeak_speaks_a_phrase() -> None:
    frames = speak_to_frames("one point two metres, left", SR)
    assert frames is not None and frames.shape[1] == 2 and frames.dtype == np.int16
    assert 0.5 < len(frames) / SR < 5.0
    assert np.abs(frames.astype(float)).max() > 1000
