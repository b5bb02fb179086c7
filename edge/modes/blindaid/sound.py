"""The blind aid's sound: cues rendered to stereo samples, speech, and where the samples go.

- :class:`Synth` renders a :class:`~edge.modes.blindaid.Cue` into stereo int16 frames: beeps with
  raised-cosine rise and fall at the cue's interval and pitch, a continuous tone, or silence, placed
  in the stereo field with a constant-power pan law. Its oscillator, envelope, beep schedule and
  pan carry over from call to call, so audio rendered in pieces of any size is the same stream as
  audio rendered in one go: chunks join without clicks.
- :class:`CuePlayer` turns cues stamped with their times into that continuous stream and writes it
  to a sink, chunk by chunk (see its docstring for the latency it adds).
- Sinks share one interface, :class:`AudioSink`: :class:`WavSink` (a 16-bit stereo WAV file,
  written atomically), :class:`AplaySink` (ALSA through ``aplay``), :class:`NullSink`.
- :func:`speak_to_frames` says a phrase with espeak-ng (or espeak) when installed.

Frames everywhere are numpy arrays of shape (N, 2), dtype int16: column 0 left, column 1 right.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import shutil
import struct
import subprocess
import tempfile
import threading
import wave
from pathlib import Path
from typing import Protocol

import numpy as np

from edge.errors import AudioError
from edge.fsutil import current_umask, fsync_dir
from edge.modes.blindaid.logic import BEEP, BLIND, SILENCE, TONE, BlindAidConfig, Cue, pan_gains

log = logging.getLogger(__name__)

_FULL_SCALE = 32767.0
# The "cannot see" warble: two low pitches, below every beep (pitch_low_hz >= 400 Hz by default) and
# far below the tone, alternating every WARBLE_STEP_S without a gap, from the centre. Unlike silence
# it sounds; unlike beeps it never stops; unlike the tone it moves, and is low.
WARBLE_HZ = (300.0, 225.0)
WARBLE_STEP_S = 0.125


def _as_frames(frames: np.ndarray) -> np.ndarray:
    """Check that `frames` is (N, 2) int16 and return it C-contiguous and little-endian."""
    a = np.asarray(frames)
    if a.ndim != 2 or a.shape[1] != 2 or a.dtype != np.int16:
        raise ValueError(f"audio frames must be an (N, 2) int16 array, got {a.shape} {a.dtype}")
    return np.ascontiguousarray(a, dtype="<i2")


def _slew(target: np.ndarray, r0: float, step: float) -> tuple[np.ndarray, float]:
    """Follow the piecewise-constant `target` from `r0`, moving at most `step` per sample (linear
    ramps); returns the path and its last value. Vectorised per run of equal targets."""
    n = len(target)
    out = np.empty(n)
    if n == 0:
        return out, r0
    r = r0
    edges = np.flatnonzero(np.diff(target)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [n]))
    for s, e in zip(starts, ends):
        g = float(target[s])
        k = np.arange(1, e - s + 1, dtype=np.float64)
        seg = np.minimum(g, r + step * k) if g >= r else np.maximum(g, r - step * k)
        out[s:e] = seg
        r = float(seg[-1])
    return out, r


# --- synthesis ---------------------------------------------------------------------------------


class Synth:
    """Renders cues into stereo int16 frames, one stream: state carries over between calls.

    - **beep**: a beep of ``beep_s`` (rise and fall of ``ramp_s`` each, raised cosine, included)
      every ``cue.interval_s``, at ``cue.pitch_hz``. The first beep of a cue that follows silence or
      the tone starts at once; when only the interval changes, the next beep comes at the earlier of
      its old time and the last beep + the new interval (a nearing obstacle speeds up at once).
    - **tone**: continuous at ``cue.pitch_hz``, rising and falling with the same ramps.
    - **blind** ("cannot see"): a low two-tone warble, :data:`WARBLE_HZ` alternating every
      :data:`WARBLE_STEP_S`, continuous and centred, rising with the same ramps.
    - **silence**: the sound present fades out over ``ramp_s``.

    The sine's phase runs on through pitch changes and silences (no phase jumps); the stereo gains
    follow ``cue.pan`` through :func:`~edge.modes.blindaid.pan_gains` (constant power), gliding
    over ``pan_glide_s`` while sound plays and jumping while it is silent.
    """

    def __init__(self, sample_rate: int = 22050, volume: float = 0.6, beep_s: float = 0.05,
                 ramp_s: float = 0.005, pan_glide_s: float = 0.02) -> None:
        if sample_rate <= 0:
            raise ValueError("sample_rate must be positive")
        self.sample_rate = int(sample_rate)
        self.volume = float(volume)
        self.ramp_n = max(1, round(ramp_s * sample_rate))
        self.beep_n = max(2 * self.ramp_n, round(beep_s * sample_rate))
        self.pan_glide_n = max(1, round(pan_glide_s * sample_rate))
        self._pos = 0  # absolute index of the next sample
        self._cue: Cue | None = None
        self._phase = 0.0
        self._freq = 440.0
        self._env = 0.0  # envelope ramp state, 0..1 (linear; heard through a raised cosine)
        self._interval_n = 0
        self._next_onset = 0
        self._last_onset: int | None = None
        self._gate_until = 0
        self._warble_n = max(1, round(WARBLE_STEP_S * sample_rate))
        self._warble_start = 0
        c = pan_gains(0.0)
        self._g_from = np.array(c)
        self._g_to = np.array(c)
        self._g_start = 0

    @classmethod
    def from_config(cls, config: BlindAidConfig) -> Synth:
        return cls(config.sample_rate, config.volume, config.beep_s, config.ramp_s)

    @property
    def position(self) -> int:
        """Absolute index of the next sample to be rendered."""
        return self._pos

    def render(self, cue: Cue | None, start_s: float, duration_s: float) -> np.ndarray:
        """Frames (N, 2) int16 of `cue` from stream time `start_s` for `duration_s`.

        Sample indices are ``round(t · sample_rate)``, so consecutive calls (each starting where the
        last ended) join exactly, whatever their lengths. A `start_s` elsewhere moves the stream
        there (the beep schedule carries on from the new position)."""
        n0 = round(start_s * self.sample_rate)
        n1 = round((start_s + duration_s) * self.sample_rate)
        if n0 != self._pos:
            self._jump(n0)
        return self.render_n(cue, max(0, n1 - n0))

    def render_n(self, cue: Cue | None, n: int) -> np.ndarray:
        """The next `n` frames of the stream, with `cue` (None: keep the current cue)."""
        out = self._render_float(cue, n)
        return np.clip(np.rint(out), -32768, 32767).astype(np.int16)

    # --- internals ---

    def _jump(self, pos: int) -> None:
        shift = pos - self._pos
        self._pos = pos
        self._next_onset += shift
        self._gate_until += shift
        self._warble_start += shift
        self._g_start += shift
        if self._last_onset is not None:
            self._last_onset += shift

    def _gains_at(self, pos: int) -> np.ndarray:
        frac = min(1.0, max(0.0, (pos - self._g_start) / self.pan_glide_n))
        return self._g_from + (self._g_to - self._g_from) * frac

    def _apply(self, cue: Cue) -> None:
        prev = self._cue
        pos = self._pos
        if cue.sound == BEEP:
            self._interval_n = max(self.beep_n + 1, round((cue.interval_s or 1.0) * self.sample_rate))
            if prev is None or prev.sound != BEEP or self._last_onset is None:
                self._next_onset = pos
            else:
                self._next_onset = max(pos, min(self._next_onset, self._last_onset + self._interval_n))
        else:
            self._gate_until = pos
            self._last_onset = None
        if cue.sound == BLIND:
            self._warble_start = pos
        if cue.sound != SILENCE:
            if cue.pitch_hz and cue.sound != BLIND:
                self._freq = float(cue.pitch_hz)
            target = np.array(pan_gains(0.0 if cue.sound == BLIND else cue.pan))
            if not np.allclose(target, self._g_to):
                if self._env <= 0.0:  # nothing is sounding: jump
                    self._g_from, self._g_to, self._g_start = target, target, pos
                else:
                    self._g_from, self._g_to, self._g_start = self._gains_at(pos), target, pos
        self._cue = cue

    def _render_float(self, cue: Cue | None, n: int) -> np.ndarray:
        """(n, 2) float64 in int16 units, not yet rounded or clipped."""
        if cue is not None and _sound_of(cue) != _sound_of(self._cue):
            self._apply(cue)
        pos0 = self._pos
        gate = np.zeros(n)
        c = self._cue
        if c is not None and c.sound in (TONE, BLIND):
            gate[:] = 1.0
        elif c is not None and c.sound == BEEP:
            gate_n = self.beep_n - self.ramp_n  # the fall follows the gate's end
            if self._gate_until > pos0:
                gate[: min(n, self._gate_until - pos0)] = 1.0
            while self._next_onset < pos0 + n:
                a = self._next_onset - pos0
                gate[max(a, 0): max(0, min(a + gate_n, n))] = 1.0
                self._gate_until = self._next_onset + gate_n
                self._last_onset = self._next_onset
                self._next_onset += self._interval_n
        ramp, self._env = _slew(gate, self._env, 1.0 / self.ramp_n)
        amp = 0.5 - 0.5 * np.cos(np.pi * ramp)
        phase: np.ndarray
        if c is not None and c.sound == BLIND:  # the pitch steps; the phase runs on (no clicks)
            step = (np.arange(pos0, pos0 + n) - self._warble_start) // self._warble_n
            w_n = 2.0 * math.pi * np.where(step % 2 == 0, WARBLE_HZ[0], WARBLE_HZ[1]) / self.sample_rate
            phase = self._phase + np.concatenate(([0.0], np.cumsum(w_n)[:-1]))[:n]
            self._phase = math.fmod(self._phase + float(w_n.sum()), 2.0 * math.pi)
        else:
            w = 2.0 * math.pi * self._freq / self.sample_rate
            phase = self._phase + w * np.arange(n)
            self._phase = math.fmod(self._phase + w * n, 2.0 * math.pi)
        mono = (self.volume * _FULL_SCALE) * amp * np.sin(phase)
        idx = np.arange(pos0, pos0 + n)
        frac = np.clip((idx - self._g_start) / self.pan_glide_n, 0.0, 1.0)[:, None]
        gains = self._g_from + (self._g_to - self._g_from) * frac
        self._pos = pos0 + n
        return mono[:, None] * gains


def _sound_of(cue: Cue | None) -> tuple | None:
    """What of a cue the synthesiser hears (speech and metadata aside)."""
    if cue is None:
        return None
    if cue.sound in (SILENCE, BLIND):
        return (cue.sound,)
    return (cue.sound, cue.interval_s, cue.pitch_hz, cue.pan)


# --- sinks -------------------------------------------------------------------------------------


class AudioSink(Protocol):
    """Where frames go. `write` takes (N, 2) int16 frames; `close` ends the stream."""

    sample_rate: int

    def write(self, frames: np.ndarray) -> None: ...

    def close(self) -> None: ...


class NullSink:
    """Discards the frames; counts them (benchmarks, tests)."""

    def __init__(self, sample_rate: int = 22050) -> None:
        self.sample_rate = sample_rate
        self.frames = 0
        self.closed = False

    def write(self, frames: np.ndarray) -> None:
        self.frames += len(_as_frames(frames))

    def close(self) -> None:
        self.closed = True


class WavSink:
    """A 16-bit stereo WAV file at `path`, written atomically.

    The frames go to a hidden temporary file beside `path` (``.<name>.*.tmp``); :meth:`close`
    fsyncs it and renames it over `path`, so `path` holds the old file or the whole new one, never
    half of one. The temporary file's header is rewritten after every write (and flushed), so if
    the process is killed the temporary file is still a valid WAV of everything written so far;
    it is left in place for you to rename or delete.
    """

    def __init__(self, path: str | Path, sample_rate: int = 22050) -> None:
        self.path = Path(path)
        self.sample_rate = int(sample_rate)
        folder = self.path.parent if str(self.path.parent) else Path(".")
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=folder)
            os.fchmod(fd, 0o666 & ~current_umask())  # a WAV to listen to, not a secret
        except OSError as exc:
            raise AudioError(f"audio: cannot write {self.path}: {exc.strerror}") from None
        self.tmp_path = Path(tmp)
        self._fh = os.fdopen(fd, "w+b")
        self._wav = wave.open(self._fh, "wb")
        self._wav.setnchannels(2)
        self._wav.setsampwidth(2)
        self._wav.setframerate(self.sample_rate)
        self._wav.writeframes(b"")  # the header, at once
        self._fh.flush()
        self.frames = 0
        self.closed = False

    def write(self, frames: np.ndarray) -> None:
        if self.closed:
            raise ValueError(f"{self.path}: write after close")
        data = _as_frames(frames)
        self._wav.writeframes(data.tobytes())  # patches the header's sizes too
        self._fh.flush()
        self.frames += len(data)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._wav.close()  # final header; does not close our file object
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        os.replace(self.tmp_path, self.path)
        fsync_dir(self.path.parent)  # the rename itself, through a power cut

    def discard(self) -> None:
        """Give up: remove the temporary file, leave `path` as it was."""
        if self.closed:
            return
        self.closed = True
        self._wav.close()
        self._fh.close()
        self.tmp_path.unlink(missing_ok=True)

    def __enter__(self) -> WavSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class AplaySink:
    """ALSA playback through ``aplay`` reading raw S16_LE stereo from a pipe (alsa-utils; on every
    Raspberry Pi OS image). `buffer_ms` sets ALSA's buffer (``--buffer-time``): playback starts when
    it is full, and it is latency that every sound waits through, so keep it small (the player
    writes just ahead of the clock); raise it if you hear gaps (underruns). `device` is an ALSA
    device name (``aplay -L``), default the system's default."""

    def __init__(self, sample_rate: int = 22050, device: str | None = None, buffer_ms: int = 80,
                 executable: str = "aplay") -> None:
        self.sample_rate = int(sample_rate)
        exe = shutil.which(executable)
        if exe is None:
            raise AudioError(
                f"audio: {executable} not found on PATH; install alsa-utils (apt install alsa-utils) "
                "or write the sound to a file with --audio-out FILE.wav"
            )
        args = [exe, "-q", "-t", "raw", "-f", "S16_LE", "-c", "2", "-r", str(self.sample_rate),
                f"--buffer-time={int(buffer_ms) * 1000}"]
        if device:
            args += ["-D", device]
        self._stderr = tempfile.TemporaryFile()
        try:
            self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                          stderr=self._stderr, bufsize=0)
        except OSError as exc:
            self._stderr.close()
            raise AudioError(f"audio: cannot start {exe}: {exc.strerror}") from None
        self.closed = False

    def _died(self) -> AudioError:
        rc = self._proc.wait()
        self._stderr.seek(0)
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        why = f": {lines[-1]}" if lines else ""
        return AudioError(f"audio: aplay stopped (exit status {rc}){why}")

    def write(self, frames: np.ndarray) -> None:
        data = _as_frames(frames).tobytes()
        if self._proc.poll() is not None:
            raise self._died()
        view = memoryview(data)
        try:
            assert self._proc.stdin is not None
            while view:  # an unbuffered pipe may take part of it
                view = view[self._proc.stdin.write(view) or 0:]
        except (BrokenPipeError, ConnectionResetError):
            raise self._died() from None

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            if self._proc.stdin is not None:
                self._proc.stdin.close()
        except OSError:
            pass
        try:
            self._proc.wait(timeout=5.0)  # it plays what is buffered, then ends
        except subprocess.TimeoutExpired:
            self._proc.terminate()
            self._proc.wait(timeout=2.0)
        self._stderr.close()


def open_sink(target: str, sample_rate: int) -> AudioSink:
    """A sink from a command-line word: ``alsa``/``aplay`` (or ``alsa:DEVICE``), ``null``, or a
    WAV file path (``--audio-out``)."""
    if target in ("alsa", "aplay"):
        return AplaySink(sample_rate)
    if target.startswith("alsa:"):
        return AplaySink(sample_rate, device=target[5:])
    if target == "null":
        return NullSink(sample_rate)
    return WavSink(target, sample_rate)


# --- speech ------------------------------------------------------------------------------------

_SPEECH_MISSING_LOGGED = False


def speech_engine() -> str | None:
    """The path of espeak-ng (or espeak) on PATH, or None."""
    return shutil.which("espeak-ng") or shutil.which("espeak")


def parse_wav_bytes(data: bytes) -> tuple[int, np.ndarray]:
    """(sample rate, samples (N, channels) float64 in int16 units) of a PCM WAV in memory.

    Tolerant of streamed WAVs whose RIFF and data sizes are placeholders (espeak-ng writes
    0x7ffff000 when its output is a pipe): the data runs to the end of the bytes."""
    if len(data) < 12 or data[:4] != b"RIFF" or data[8:12] != b"WAVE":
        raise ValueError("not a RIFF/WAVE stream")
    off = 12
    fmt = None
    while off + 8 <= len(data):
        cid, size = data[off:off + 4], struct.unpack_from("<I", data, off + 4)[0]
        body = off + 8
        if cid == b"fmt ":
            tag, channels, rate, _, _, bits = struct.unpack_from("<HHIIHH", data, body)
            fmt = (tag, channels, rate, bits)
        elif cid == b"data":
            if fmt is None:
                raise ValueError("WAV data before its fmt chunk")
            tag, channels, rate, bits = fmt
            if tag not in (1, 0xFFFE) or bits not in (8, 16) or channels < 1:
                raise ValueError(f"unsupported WAV format (tag {tag}, {bits} bits, {channels} channels)")
            raw = data[body: body + size]
            width = bits // 8
            raw = raw[: len(raw) // (width * channels) * width * channels]
            if bits == 16:
                samples = np.frombuffer(raw, dtype="<i2").astype(np.float64)
            else:
                samples = (np.frombuffer(raw, dtype=np.uint8).astype(np.float64) - 128.0) * 256.0
            return rate, samples.reshape(-1, channels)
        off = body + size + (size & 1)
    raise ValueError("WAV without a data chunk")


def resample_linear(samples: np.ndarray, rate_in: int, rate_out: int) -> np.ndarray:
    """(N, C) samples at `rate_in` → (M, C) at `rate_out`, M = round(N·rate_out/rate_in), by linear
    interpolation (plenty for speech at these rates)."""
    samples = np.asarray(samples, dtype=np.float64)
    if rate_in == rate_out or len(samples) == 0:
        return samples.copy()
    m = max(1, round(len(samples) * rate_out / rate_in))
    x = np.arange(m) * (rate_in / rate_out)
    xp = np.arange(len(samples))
    return np.stack([np.interp(x, xp, samples[:, c]) for c in range(samples.shape[1])], axis=1)


def speak_to_frames(text: str, sample_rate: int = 22050, volume: float = 1.0, voice: str | None = None,
                    words_per_minute: int = 175) -> np.ndarray | None:
    """`text` spoken by espeak-ng (or espeak) as stereo int16 frames (N, 2) at `sample_rate`, centred;
    None when neither is installed (logged once at info) or the engine fails (logged as a warning).

    No shell is involved: the engine runs from an argument list and `text` is one argument. Results
    are cached (the blind aid says the same few phrases again and again), read-only. espeak-ng
    takes some 50-200 ms per phrase on a Pi: call it off the loop that must keep time, or early."""
    global _SPEECH_MISSING_LOGGED
    exe = speech_engine()
    if exe is None:
        if not _SPEECH_MISSING_LOGGED:
            log.info("speech: espeak-ng is not installed, distances are not spoken (apt install espeak-ng)")
            _SPEECH_MISSING_LOGGED = True
        return None
    return _speak_cached(exe, text, int(sample_rate), float(volume), voice, int(words_per_minute))


@functools.lru_cache(maxsize=64)
def _speak_cached(exe: str, text: str, sample_rate: int, volume: float, voice: str | None,
                  wpm: int) -> np.ndarray | None:
    # A leading '-' would read as an option; a leading space keeps it text.
    arg = " " + text if text.startswith("-") else text
    args = [exe, "--stdout", "-s", str(wpm)] + (["-v", voice] if voice else []) + [arg]
    try:
        proc = subprocess.run(args, capture_output=True, timeout=10.0, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.warning("speech: %s failed: %s", os.path.basename(exe), exc)
        return None
    if proc.returncode != 0 or not proc.stdout:
        why = proc.stderr.decode(errors="replace").strip().splitlines()
        log.warning("speech: %s exited with status %d%s", os.path.basename(exe), proc.returncode,
                    f": {why[-1]}" if why else "")
        return None
    try:
        rate, samples = parse_wav_bytes(proc.stdout)
    except (ValueError, struct.error) as exc:
        log.warning("speech: cannot read %s's output: %s", os.path.basename(exe), exc)
        return None
    mono = resample_linear(samples, rate, sample_rate).mean(axis=1) * volume
    frames = np.clip(np.rint(mono), -32768, 32767).astype(np.int16)
    out = np.ascontiguousarray(np.stack([frames, frames], axis=1))
    out.flags.writeable = False
    return out


# --- the player --------------------------------------------------------------------------------


class CuePlayer:
    """The continuous audio stream of a run: cues (and speech) with their times in, frames out.

    The stream is cut into chunks of `chunk_s` on a fixed grid from `start_s` (stream time = the
    caller's clock, seconds). A cue stamped `t` takes effect at the first chunk boundary at or after
    `t` that is not yet written; its sound starts there (a first beep or the tone at once), so the
    player adds at most `chunk_s` of latency to the moment of the cue, plus, on a live sink,
    `lead_s` (how far ahead of the clock it writes) and the device's buffer.

    Use: ``set_cue(cue, t)`` / ``say(frames, t)`` whenever they happen (from any thread), and
    ``advance(now)`` periodically (at least every ``chunk_s`` on a live sink): it writes every chunk
    that starts before ``now + lead_s``, so all samples up to ``now`` are written (rounded up to the
    chunk boundary). ``close(t_end)`` writes exactly up to `t_end` (a last partial chunk) and closes
    the sink. For a WAV of a simulated run, pass the simulated times and ``lead_s = 0``: the file is
    the run's timeline, each cue at its time rounded up to the chunk.

    Speech is mixed over the beeps, which are ducked to `duck` while it plays. ``starts`` lists
    (cue time, stream time its samples start) for latency measurements.
    """

    def __init__(self, synth: Synth, sink: AudioSink, chunk_s: float = 0.02, lead_s: float = 0.0,
                 start_s: float = 0.0, duck: float = 0.35) -> None:
        self.synth = synth
        self.sink = sink
        self.sample_rate = synth.sample_rate
        self.chunk_n = max(1, round(chunk_s * self.sample_rate))
        self.lead_s = lead_s
        self.start_s = start_s
        self.duck = duck
        self._written = 0  # samples of the stream written
        self._cues: list[tuple[int, float, Cue]] = []  # (due sample, time, cue), in due order
        self._speech_due: list[tuple[int, np.ndarray]] = []
        self._speech = np.zeros((0, 2))  # speech still to play, float
        self._duck_state = 1.0
        self._lock = threading.Lock()
        self.cue = Cue()
        self.starts: list[tuple[float, float]] = []
        self.closed = False

    @property
    def position_s(self) -> float:
        """Stream time up to which samples are written."""
        return self.start_s + self._written / self.sample_rate

    def _sample(self, t_s: float) -> int:
        return max(0, math.ceil((t_s - self.start_s) * self.sample_rate - 1e-6))

    def _due(self, t_s: float) -> int:
        """First chunk boundary at or after `t_s`, and not before what is written."""
        s = self._sample(t_s)
        boundary = -(-s // self.chunk_n) * self.chunk_n
        return max(boundary, self._written)

    def set_cue(self, cue: Cue, t_s: float) -> None:
        """`cue` from time `t_s` on (applied at the next chunk boundary)."""
        with self._lock:
            self._cues.append((self._due(t_s), t_s, cue))
            self._cues.sort(key=lambda x: x[0])

    def say(self, frames: np.ndarray | None, t_s: float) -> None:
        """Mix speech `frames` (N, 2) int16 in from `t_s` (after any speech still playing)."""
        if frames is None or len(frames) == 0:
            return
        with self._lock:
            self._speech_due.append((self._due(t_s), _as_frames(frames).astype(np.float64)))
            self._speech_due.sort(key=lambda x: x[0])

    def advance(self, t_s: float, cue: Cue | None = None) -> int:
        """Write the stream up to `t_s` + lead_s (rounded up to the chunk grid); with `cue`, first
        ``set_cue(cue, t_s)``. Returns the frames written."""
        if cue is not None:
            self.set_cue(cue, t_s)
        with self._lock:
            s = self._sample(t_s + self.lead_s)
            return self._write_until(-(-s // self.chunk_n) * self.chunk_n)

    def finish(self, t_s: float) -> int:
        """Write exactly up to `t_s` (nothing if already past it)."""
        with self._lock:
            return self._write_until(self._sample(t_s))

    def close(self, t_s: float | None = None) -> None:
        """Write up to `t_s` (if given) and close the sink."""
        if self.closed:
            return
        if t_s is not None:
            self.finish(t_s)
        self.closed = True
        self.sink.close()

    def _write_until(self, end: int) -> int:
        total = 0
        while self._written < end:
            pos = self._written
            stop = min(end, (pos // self.chunk_n + 1) * self.chunk_n)
            while self._cues and self._cues[0][0] <= pos:
                _, t_cue, cue = self._cues.pop(0)
                self.cue = cue
                self.starts.append((t_cue, self.start_s + pos / self.sample_rate))
            while self._speech_due and self._speech_due[0][0] <= pos:
                self._speech = np.concatenate((self._speech, self._speech_due.pop(0)[1]))
            n = stop - pos
            out = self.synth._render_float(self.cue, n)
            k = min(n, len(self._speech))
            target = np.ones(n)
            target[:k] = self.duck
            duck, self._duck_state = _slew(target, self._duck_state, 1.0 / self.synth.ramp_n / 2)
            out *= duck[:, None]
            if k:
                out[:k] += self._speech[:k]
                self._speech = self._speech[k:]
            self.sink.write(np.clip(np.rint(out), -32768, 32767).astype(np.int16))
            self._written = stop
            total += n
        return total


def read_wav(path: str | Path) -> tuple[int, np.ndarray]:
    """(sample rate, frames (N, channels) int16) of a 16-bit WAV file (tests, tools)."""
    with wave.open(str(path), "rb") as w:
        if w.getsampwidth() != 2:
            raise ValueError(f"{path}: not 16-bit")
        data = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
        return w.getframerate(), data.reshape(-1, w.getnchannels()).astype(np.int16)


__all__ = [
    "AplaySink", "AudioSink", "CuePlayer", "NullSink", "Synth", "WavSink", "open_sink",
    "parse_wav_bytes", "read_wav", "resample_linear", "speak_to_frames", "speech_engine",
]
