"""A long linear echo canceller and a per-band residual echo suppressor, for double talk.

WebRTC AEC3 (through livekit, which exposes no tuning) models ~50 ms of echo path and leaves the
rest to a suppressor that also takes the user down while the robot talks: with the robot's echo
as loud as the user at the mic, the user came out of AEC3 correlating ~0.6 with what they said
(0.4 with the whole-frame guard after it). This pair keeps the near end linear instead:

- LinearEchoCanceller: a partitioned-block frequency-domain adaptive filter (overlap-save, one
  10 ms block per partition) covering the room response, adapted as a frequency-domain Kalman
  filter: each partition and bin keeps how uncertain its coefficient still is, and its step is
  that uncertainty against what the error holds besides (so steps are large while the filter is
  new and shrink as it converges or someone talks; on the robot's voice it is 2-4 dB further
  along than the NLMS it replaced after 3-8 s). Two copies: a background filter adapts on every
  block; the foreground filter, whose output is used, takes the background's coefficients when
  they cancel better and no double talk is detected (the output jumps against the mic above
  what echo alone leaves, and above the echo its own variances say it may still miss: a new
  filter's error jumps with every syllable it has not heard yet). An output louder than the mic
  is no voice but a changed echo path: learning restarts as at the start (from the current
  coefficients) instead of freezing.
  Its output is mic minus the echo estimate: the user's voice is not touched.
- ResidualEchoSuppressor: per frequency bin, the echo the filter leaves is estimated from the
  filter's echo estimate, from the reference's envelope (for what the filter has not learned
  yet) and from the filter's own uncertainty, with per-band shares learned as running medians
  over bands the user is not clearly above, held with a reverberant decay; bins where it
  dominates are turned down softly, bins where the user dominates pass almost whole, and frames
  with nothing clearly above it (for two blocks running) are taken down whole (residual speech
  must not start utterances in the VAD). Only that whole-frame decision uses the estimate held
  with the room's decay; the per-bin gain uses the current one, which already holds the tail the
  filter spans (its echo estimate, the held reference envelope, its variances over all
  partitions); held twice, it went on taking the user down after each loud syllable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array

FloatArray = npt.NDArray[np.float64]
ComplexArray = npt.NDArray[np.complex128]

INT16_SCALE = 32768.0
REFERENCE_FLOOR = 1e-6  # reference power per sample (-60 dBFS) below which nothing adapts
ECHO_LEFT_STEP_DB = 0.2  # double-talk detector's quantile tracker: step down per block...
ECHO_LEFT_QUANTILE = 0.5  # ... and up by STEP * q / (1 - q): slow, so a voice cannot drag it up
DOUBLE_TALK_SMOOTHING = 0.3  # error and mic energies for the detector: weight of the newest block
DOUBLE_TALK_HOLD_BLOCKS = 30  # once detected, double talk is assumed this many blocks more
DOUBLE_TALK_STEP = 0.25  # the background's step in double talk, relative to the usual
DOUBLE_TALK_CREEP_DB = 0.02  # the detector's tracker creeps up this much per double-talk block
COMPARE_SMOOTHING = 0.3  # background vs foreground error energy: weight of the newest block
COPY_RATIO = 1.0  # background error below the foreground's (smoothed): copy it over
# The output louder than the mic (by this much, in this many blocks more than not): no voice does
# that (it adds to the echo), an echo path change does (the filter subtracts the wrong echo).
PATH_CHANGE_DB = 1.0
PATH_CHANGE_BLOCKS = 20
RESET_RATIO = 4.0  # background error this far above the foreground's (+6 dB): it diverged, reset
RESIDUAL_BANDS = 16  # the residual's shares of the estimate and of the reference, learned per band
RESIDUAL_INITIAL_DB = 0.0  # before learning: residual as loud as the estimate
RESIDUAL_STEP_DB = 0.2  # quantile tracker: step down per block (20 dB/s at 10 ms)...
RESIDUAL_QUANTILE = 0.5  # ... and up by STEP * q / (1 - q): the median (a voice cannot drag it up)
RESIDUAL_OVERESTIMATE = 4.0  # gain = 1 - this x residual / power (the residual is a median: 6 dB up)
COUPLING_INITIAL_DB = 6.0  # before learning: echo up to 6 dB louder than the reference
COUPLING_WARMUP_BLOCKS = 150  # the first 1.5 s of reference: the coupling is learned down slower...
COUPLING_WARMUP_STEP_DB = 0.05  # ... at this step (5 dB/s): the new filter's error swings widely
USER_EVIDENCE = 0.1  # energy clearly above the residual, against the residual (-10 dB), that is the user
RESIDUAL_MUTE_DB = -60.0  # frames with echo alone (nothing clearly above the residual) go down this
USER_ONSET_BLOCKS = 2  # the user is evident in this many blocks running before a frame opens
USER_HANGOVER_BLOCKS = 10  # after the user was evident, blocks not muted whole (100 ms)
ECHO_FLOOR = 1e-8  # echo estimate power per sample (-80 dBFS) below which a band is not learned
INITIAL_UNCERTAINTY = 0.006  # Kalman: coefficient variance per partition and bin before learning
FORGET = 0.999  # Kalman: coefficients decay this much per block, their variance grows back (tracking)
# What the pair learned, remembered across a restart (audio/echo_memory.py), is on trial for the
# first REMEMBERED_TRIAL_BLOCKS of the robot's voice: an output louder than the mic there (the
# path-change rule) says it is another room's, and the pair starts new.
REMEMBERED_TRIAL_BLOCKS = 300
REMEMBERED_CHECK_BLOCKS = 50  # ... and after this many, checked against the echo it left when kept:
REMEMBERED_WORSE_DB = 6.0  # this much more left (median) says the room changed: it relearns the room
REMEMBER_ECHO_LEFT_DB = -10.0  # a path is worth remembering once it leaves the echo this far down
ERROR_SMOOTHING = 0.8  # Kalman: error power per bin (what the echo model does not explain): old weight


@dataclass
class LinearEchoStats:
    blocks: int = 0
    foreground_updates: int = 0  # background coefficients copied to the output filter
    background_resets: int = 0  # background diverged (double talk) and restarted from the foreground
    double_talk_blocks: int = 0  # blocks judged double talk: slow background, no copy to the output
    path_changes: int = 0  # output louder than the mic (the echo path changed): learning restarted
    remembered_dropped: int = 0  # a remembered echo path that did not fit this room: started new
    remembered_relearned: int = 0  # one whose room changed (the body's path held): relearning the room


@dataclass(frozen=True)
class LearnedEcho:
    """What the canceller and its residual suppressor learned of the room: enough to start a
    later pair where this one is (audio/echo_memory.py keeps it across restarts)."""

    coefficients: ComplexArray  # the output filter, partitions x bins
    variances: FloatArray  # how sure each coefficient is, partitions x bins
    echo_left_db: float  # output vs mic in single talk (-ERLE)
    residual_db: FloatArray  # the suppressor's per-band shares of the echo estimate...
    coupling_db: FloatArray  # ... and of the reference's envelope


class LinearEchoCanceller:
    """Removes the linear echo of `reference` from `mic`, one `block` of samples at a time.

    Output sample i is the mic's sample i minus the echo predicted from the reference up to i
    (no added delay). The filter spans `partitions` blocks of reference history."""

    def __init__(self, block: int, partitions: int, step: float, margin_db: float) -> None:
        if block <= 0 or partitions <= 0:
            raise ValueError(f"block and partitions must be positive, got {block}, {partitions}")
        if not 0.0 < step <= 1.0:
            raise ValueError(f"step must be in (0, 1], got {step}")
        self.block = block
        self.partitions = partitions
        self._step = step
        self._margin_db = margin_db
        self.echo_left_db = 0.0  # output vs mic in single talk (-ERLE), learned
        self._error_energy = 0.0
        self._hold = 0  # blocks double talk is still assumed
        self._louder_run = 0  # blocks with the output louder than the mic, less those without
        self._mic_energy = 0.0
        self._up_db = ECHO_LEFT_STEP_DB * ECHO_LEFT_QUANTILE / (1 - ECHO_LEFT_QUANTILE)
        self._fft = 2 * block
        bins = block + 1
        self._reference = np.zeros(self._fft)  # last two blocks of reference, overlap-save
        self._history = np.zeros((partitions, bins), dtype=np.complex128)  # X of the latest blocks
        self._background = np.zeros((partitions, bins), dtype=np.complex128)
        self._foreground = np.zeros((partitions, bins), dtype=np.complex128)
        self._history_power = np.zeros((partitions, bins))
        self._uncertainty = np.full((partitions, bins), INITIAL_UNCERTAINTY)  # background's
        self._foreground_uncertainty = self._uncertainty.copy()  # as it was when last copied
        self._error_power = np.zeros(bins)
        # Echo the foreground may still miss per bin (its coefficients' variance x the reference).
        self.uncertain_echo: FloatArray = np.zeros(bins)
        self._uncertain_smoothed = 0.0  # its energy per block, smoothed as the detector's energies
        self._background_error = 0.0
        self._foreground_error = 0.0
        self._constrain_next = 0  # one partition per block is made causal again (round robin)
        self._trial_blocks = 0  # blocks of the robot's voice a remembered path is still on trial for
        self._trial_ratios: list[float] | None = None  # output vs mic (dB) in the trial's first blocks
        self._remembered_left_db = 0.0  # the echo the remembered state left
        self.echo_spectrum: ComplexArray = np.zeros(bins, dtype=np.complex128)  # of the last block
        self.stats = LinearEchoStats()

    @property
    def reference_spectrum(self) -> ComplexArray:
        """Spectrum of the reference's latest two blocks."""
        latest: ComplexArray = self._history[0]
        return latest

    @property
    def coefficients_shape(self) -> tuple[int, int]:
        """(partitions, bins) of an echo path this canceller can start from."""
        return (self.partitions, self.block + 1)

    @property
    def worth_remembering(self) -> bool:
        """It cancels REMEMBER_ECHO_LEFT_DB or more in single talk, and is not on trial."""
        return self.echo_left_db <= REMEMBER_ECHO_LEFT_DB and self._trial_blocks == 0

    def learned(self) -> tuple[ComplexArray, FloatArray, float]:
        """The output filter's coefficients and variances (copies), and the echo it leaves."""
        return self._foreground.copy(), self._foreground_uncertainty.copy(), self.echo_left_db

    def start_from(self, coefficients: ComplexArray, variances: FloatArray, echo_left_db: float) -> None:
        """Start where a canceller of this shape was (`learned`): the echo is cancelled from the
        first block instead of after seconds of learning, and the suppressor can trust it. On
        trial for its first REMEMBERED_TRIAL_BLOCKS of the robot's voice."""
        shape = self.coefficients_shape
        if coefficients.shape != shape or variances.shape != shape:
            raise ValueError(f"echo path of shape {coefficients.shape}, this canceller's is {shape}")
        if not (np.all(np.isfinite(coefficients)) and np.all(np.isfinite(variances))):
            raise ValueError("echo path has values that are not finite")
        self._foreground = coefficients.astype(np.complex128, copy=True)
        self._background = self._foreground.copy()
        self._uncertainty = variances.astype(np.float64, copy=True)
        self._foreground_uncertainty = self._uncertainty.copy()
        self.echo_left_db = self._remembered_left_db = echo_left_db
        self._trial_blocks = REMEMBERED_TRIAL_BLOCKS
        self._trial_ratios = []

    def process(self, mic: FloatArray, reference: FloatArray) -> FloatArray:
        """`mic` minus the echo of `reference` (both one block, full scale 1.0) played meanwhile."""
        n = self.block
        self._reference[:n] = self._reference[n:]
        self._reference[n:] = reference
        self._history = np.roll(self._history, 1, axis=0)
        self._history[0] = np.fft.rfft(self._reference)
        self._history_power = self._history.real**2 + self._history.imag**2

        foreground_echo = np.einsum("pk,pk->k", self._foreground, self._history)
        background_echo = np.einsum("pk,pk->k", self._background, self._history)
        foreground_error = mic - np.fft.irfft(foreground_echo, self._fft)[n:]
        background_error = mic - np.fft.irfft(background_echo, self._fft)[n:]
        if float(np.dot(reference, reference)) > REFERENCE_FLOOR * n:
            # In double talk the background keeps learning, slower, and the output filter takes
            # nothing from it: what it learns there may be the user's voice.
            self._trial_blocks = max(0, self._trial_blocks - 1)
            double_talk = self._double_talk(foreground_error, mic, self._uncertain_energy())
            self._adapt(background_error, DOUBLE_TALK_STEP if double_talk else 1.0)
            self._compare(foreground_error, background_error, copy=not double_talk)
        self.echo_spectrum = foreground_echo
        self._uncertain_energy()  # for the suppressor: the foreground may have just been copied
        self.stats.blocks += 1
        return foreground_error

    def _uncertain_energy(self) -> float:
        """Updates `uncertain_echo` for the latest reference and the foreground's variances;
        returns it as the error energy per block (sample domain) it stands for."""
        self.uncertain_echo = 0.5 * np.einsum("pk,pk->k", self._history_power, self._foreground_uncertainty)
        # Parseval on the zero-padded frame: the block's energy is the half spectrum's over n.
        return float(np.sum(self.uncertain_echo)) / self.block

    def _adapt(self, error: FloatArray, scale: float) -> None:
        """One Kalman step of the background filter (diagonal, per partition and bin): gain =
        coefficient variance against the error power the model predicts plus what the error
        holds besides (noise, the user, the room's tail), so a new filter learns fast and one
        that has converged, or hears someone talk, hardly moves."""
        n = self.block
        padded = np.zeros(self._fft)
        padded[n:] = error
        spectrum = np.fft.rfft(padded)
        a = ERROR_SMOOTHING
        self._error_power = a * self._error_power + (1 - a) * (spectrum.real**2 + spectrum.imag**2)
        variance = self._uncertainty
        # 0.5: an error block is half of the FFT frame (overlap-save)
        predicted = 0.5 * np.einsum("pk,pk->k", self._history_power, variance)
        gain = scale * self._step * variance / (predicted + self._error_power + 1e-12)
        self._background += gain * np.conj(self._history) * spectrum
        # Unconstrained updates let a partition's impulse response wrap around; constrain one
        # partition per block (its second half zeroed in time) so no error builds up.
        p = self._constrain_next
        taps = np.fft.irfft(self._background[p], self._fft)
        taps[n:] = 0.0
        self._background[p] = np.fft.rfft(taps)
        self._constrain_next = (p + 1) % self.partitions
        # What was learned is surer; the room may change, so variance grows back with the
        # coefficients' own power as they decay (a random walk).
        kept = FORGET * FORGET
        coefficient_power = self._background.real**2 + self._background.imag**2
        self._uncertainty = kept * (1 - 0.5 * gain * self._history_power) * variance
        self._uncertainty += (1 - kept) * coefficient_power
        self._background *= FORGET

    def _double_talk(self, error: FloatArray, mic: FloatArray, uncertain: float) -> bool:
        """True when the output is `margin_db` louder against the mic than echo alone leaves it
        (a running quantile, learned from the other blocks) and louder than the echo the filter
        may still miss (`uncertain`, energy per block): someone is talking, freeze."""
        # Energies smoothed over a few blocks: the robot's pauses (error ~ mic, both quiet) weigh
        # little against its syllables, so the ratio stays near -ERLE until someone talks.
        a = DOUBLE_TALK_SMOOTHING
        self._error_energy = (1 - a) * self._error_energy + a * float(np.dot(error, error))
        self._mic_energy = (1 - a) * self._mic_energy + a * float(np.dot(mic, mic))
        self._uncertain_smoothed = (1 - a) * self._uncertain_smoothed + a * uncertain
        ratio = 10 * math.log10((self._error_energy + 1e-12) / (self._mic_energy + 1e-12))
        self._louder_run = self._louder_run + 1 if ratio > PATH_CHANGE_DB else max(0, self._louder_run - 1)
        if self._louder_run >= PATH_CHANGE_BLOCKS:
            # The echo path changed (the robot moved, a stamp shifted within tolerance): as at
            # the start, how much echo is left is unknown (so nothing counts as double talk
            # yet) and the background learns as if new; a converged one would take seconds.
            self._restart_learning()
            if self._trial_blocks > 0:  # a remembered path of another room: worse than none
                self.stats.remembered_dropped += 1
                self._trial_blocks = 0
                self._foreground = np.zeros_like(self._foreground)
                self._background = np.zeros_like(self._background)
                self._foreground_uncertainty = self._uncertainty.copy()
                self._error_power[:] = 0.0  # what the wrong path left: it would slow the new start
        elif self._trial_ratios is not None:
            self._check_remembered(ratio)
        # A new filter's output jumps with each syllable it has not learned; its variances say
        # so. Taken for double talk, that froze it at a few dB of ERLE for seconds.
        unexplained = self._error_energy > self._uncertain_smoothed
        if ratio > self.echo_left_db + self._margin_db and unexplained:
            self._hold = DOUBLE_TALK_HOLD_BLOCKS  # the user's quieter syllables come next
        if self._hold > 0:
            self._hold -= 1
            self.echo_left_db += DOUBLE_TALK_CREEP_DB  # an echo path change must not freeze it for good
            self.stats.double_talk_blocks += 1
            return True
        self.echo_left_db += self._up_db if ratio > self.echo_left_db else -ECHO_LEFT_STEP_DB
        return False

    def _restart_learning(self) -> None:
        self.stats.path_changes += 1
        self._louder_run = 0
        self.echo_left_db = 0.0
        np.maximum(self._uncertainty, INITIAL_UNCERTAINTY, out=self._uncertainty)
        self._hold = 0

    def _check_remembered(self, ratio: float) -> None:
        """A remembered state that cancels the body's path but not the room's tail (the robot was
        moved) leaves its output well above the echo it remembers leaving, yet under the mic. Sure
        of itself, it took that residual for double talk and did not learn it away (held-out rooms:
        sentences over the first reply went unheard). The median of the first
        REMEMBERED_CHECK_BLOCKS says which (a user talking meanwhile moves it less than a room)."""
        assert self._trial_ratios is not None
        self._trial_ratios.append(ratio)
        if len(self._trial_ratios) < REMEMBERED_CHECK_BLOCKS:
            return
        if float(np.median(self._trial_ratios)) > self._remembered_left_db + REMEMBERED_WORSE_DB:
            self.stats.remembered_relearned += 1
            self._restart_learning()  # keeps the coefficients: the path through the body holds
            self._foreground_uncertainty = self._uncertainty.copy()
        self._trial_ratios = None

    def _compare(self, foreground: FloatArray, background: FloatArray, copy: bool) -> None:
        a = COMPARE_SMOOTHING
        self._foreground_error = (1 - a) * self._foreground_error + a * float(np.dot(foreground, foreground))
        self._background_error = (1 - a) * self._background_error + a * float(np.dot(background, background))
        if copy and self._background_error < COPY_RATIO * self._foreground_error:
            self._foreground = self._background.copy()
            self._foreground_uncertainty = self._uncertainty.copy()
            self._foreground_error = self._background_error
            self.stats.foreground_updates += 1
        elif self._background_error > RESET_RATIO * max(self._foreground_error, 1e-12):
            self._background = self._foreground.copy()
            self._background_error = self._foreground_error
            self.stats.background_resets += 1


class ResidualEchoSuppressor:
    """Per-bin soft suppression of what the linear canceller leaves of the echo.

    Works on windows of two blocks (sqrt-Hann, overlap-add): the output lags the input by one
    block. Per band, how loud the residual gets against the canceller's echo estimate is
    learned as a running RESIDUAL_QUANTILE quantile of (error - estimate) in dB, from blocks
    where the band is not clearly above it (`margin_db`: the user's voice is, the echo is not);
    it starts at 0 dB, strict while the filter converges. Residual per bin = that share of the
    estimate, or the reference's envelope times a learned coupling (what the filter has not
    learned yet; learned down slower for the first COUPLING_WARMUP_BLOCKS, while the new filter's
    error swings widely), or the echo the canceller's own uncertainty says it may still miss,
    held with a reverberant decay of `tail_decay_db` per block (the room's tail the filter does
    not span); gain = 1 - `overestimate` x residual / error power, at least `floor`."""

    def __init__(
        self,
        block: int,
        overestimate: float,
        floor: float,
        tail_decay_db: float,
        margin_db: float,
        mute: float,
    ) -> None:
        self.block = block
        self._fft = 2 * block
        bins = block + 1
        self._window = np.sqrt(np.hanning(self._fft + 1)[: self._fft])  # periodic: sums to 1 at hop
        self._input = np.zeros(self._fft)
        self._overlap = np.zeros(block)
        self._overestimate = overestimate
        self._floor = floor
        self._decay = 10 ** (-tail_decay_db / 10)
        self._margin_db = margin_db
        self._margin = 10 ** (margin_db / 10)
        self._mute = mute
        self._user_frames = 0  # blocks still passed softly since the user was last evident
        self._evident_run = 0  # blocks running with the user evident
        self._active_blocks = 0  # blocks with something played lately, so far
        self.frames_muted = 0  # blocks taken down whole as echo alone
        edges = np.linspace(0, bins, RESIDUAL_BANDS + 1).astype(int)
        self._band_of_bin = np.repeat(np.arange(RESIDUAL_BANDS), np.diff(edges))
        self._band_starts = edges[:-1]
        self.residual_db = np.full(RESIDUAL_BANDS, RESIDUAL_INITIAL_DB)  # per band, vs the estimate
        self.coupling_db = np.full(RESIDUAL_BANDS, COUPLING_INITIAL_DB)  # per band, vs the reference
        self._envelope = np.zeros(bins)  # reference power per bin, held with the tail's decay
        self._residual = np.zeros(bins)
        self.last_gain: FloatArray = np.ones(bins)

    def start_from(self, residual_db: FloatArray, coupling_db: FloatArray) -> None:
        """Start with what a suppressor learned before (per band), past its warm-up."""
        self.residual_db = residual_db.astype(np.float64, copy=True)
        self.coupling_db = coupling_db.astype(np.float64, copy=True)
        self._active_blocks = COUPLING_WARMUP_BLOCKS

    def relearn(self) -> None:
        """The echo path changed: what was learned of the residual no longer holds."""
        self.residual_db[:] = RESIDUAL_INITIAL_DB
        self.coupling_db[:] = COUPLING_INITIAL_DB
        self._active_blocks = 0

    def process(
        self,
        error: FloatArray,
        echo_spectrum: ComplexArray,
        reference_spectrum: ComplexArray,
        active: bool,
        uncertain_echo: FloatArray | None = None,
    ) -> FloatArray:
        """One block of canceller output; `echo_spectrum` the canceller's echo estimate for it,
        `reference_spectrum` the reference's (latest two blocks); `active` False when nothing
        played lately (then everything passes); `uncertain_echo` the echo power per bin the
        canceller may still miss (its coefficients' variance), if it knows."""
        n = self.block
        self._input[:n] = self._input[n:]
        self._input[n:] = error
        spectrum = np.fft.rfft(self._window * self._input)
        error_power = np.abs(spectrum) ** 2
        # The estimate is of an unwindowed block in a zero-padded frame: scale to this window.
        echo_power = np.abs(echo_spectrum) ** 2 * 0.5
        self._envelope = np.maximum(np.abs(reference_spectrum) ** 2 * 0.5, self._decay * self._envelope)
        if active:
            self._active_blocks += 1
            self.residual_db = self._learn(self.residual_db, error_power, echo_power)
            warm = self._active_blocks >= COUPLING_WARMUP_BLOCKS
            down_db = RESIDUAL_STEP_DB if warm else COUPLING_WARMUP_STEP_DB
            self.coupling_db = self._learn(self.coupling_db, error_power, self._envelope, down_db)
            share = 10 ** (self.residual_db[self._band_of_bin] / 10)
            coupling = 10 ** (self.coupling_db[self._band_of_bin] / 10)
            # The estimate misses what the filter has not learned yet (it starts empty): the
            # reference's envelope times the coupling left covers that until the filter has.
            estimate = np.maximum(share * echo_power, coupling * self._envelope)
            if uncertain_echo is not None:
                estimate = np.maximum(estimate, uncertain_echo)
            # Held with the room's decay for the whole-frame decision only (the robot's pauses
            # must stay muted); the gain per bin follows the estimate, which holds the tail.
            self._residual = np.maximum(estimate, self._decay * self._residual)
            gain = 1.0 - self._overestimate * estimate / (error_power + 1e-12)
            gain = np.clip(gain, self._floor, 1.0)
            # Echo alone (nothing clearly above the residual): all of the frame goes down to
            # `mute`, so what is left of the robot's voice does not sound like speech to the VAD.
            # A single block that looks like the user is more often a syllable the filter has
            # not learned: the user opens the frame after USER_ONSET_BLOCKS blocks running.
            clear = error_power > self._residual * self._margin
            evident = float(np.sum(error_power[clear])) >= float(np.sum(self._residual)) * USER_EVIDENCE
            self._evident_run = self._evident_run + 1 if evident else 0
            if evident and (self._evident_run >= USER_ONSET_BLOCKS or self._user_frames > 0):
                self._user_frames = USER_HANGOVER_BLOCKS
            elif self._user_frames <= 0:
                gain = np.full_like(gain, self._mute)
                self.frames_muted += 1
            else:
                self._user_frames -= 1
        else:
            self._residual[:] = 0.0
            gain = np.ones_like(error_power)
        self.last_gain = gain
        frame = np.fft.irfft(gain * spectrum, self._fft) * self._window
        out = self._overlap + frame[:n]
        self._overlap = frame[n:].copy()
        return out

    def _learn(
        self,
        tracker_db: FloatArray,
        error_power: FloatArray,
        echo_power: FloatArray,
        down_db: float = RESIDUAL_STEP_DB,
    ) -> FloatArray:
        """`tracker_db` (per band, error vs `echo_power`) stepped towards its RESIDUAL_QUANTILE
        quantile (`down_db` per block down), in the bands that sound and are not clearly above
        it (those are the user)."""
        error_band = np.add.reduceat(error_power, self._band_starts)
        echo_band = np.add.reduceat(echo_power, self._band_starts)
        sounding = echo_band > ECHO_FLOOR * self.block
        ratio = 10 * np.log10((error_band + 1e-15) / (echo_band + 1e-15))
        learn = sounding & (ratio <= tracker_db + self._margin_db)
        up_db = down_db * RESIDUAL_QUANTILE / (1 - RESIDUAL_QUANTILE)
        step = np.where(ratio > tracker_db, up_db, -down_db)
        updated: FloatArray = np.where(learn, tracker_db + step, tracker_db)
        return updated


def to_float(pcm: Int16Array) -> FloatArray:
    return pcm.astype(np.float64) / INT16_SCALE


class LinearAec:
    """The linear canceller, then (if `suppress_residual`) the residual suppressor, on 10 ms
    int16 frames: same interface as Aec3 (frame_samples, delay_samples, process)."""

    def __init__(
        self,
        sample_rate: int,
        frame_ms: int,
        filter_ms: int,
        step: float,
        double_talk_margin_db: float,
        suppress_residual: bool,
        residual_margin_db: float,
        residual_floor_db: float,
        tail_decay_db_per_s: float,
    ) -> None:
        self.frame_samples = sample_rate * frame_ms // 1000
        partitions = max(1, -(-filter_ms // frame_ms))
        self.canceller = LinearEchoCanceller(self.frame_samples, partitions, step, double_talk_margin_db)
        self.suppressor: ResidualEchoSuppressor | None = None
        if suppress_residual:
            self.suppressor = ResidualEchoSuppressor(
                self.frame_samples,
                overestimate=RESIDUAL_OVERESTIMATE,
                floor=10 ** (residual_floor_db / 20),
                tail_decay_db=tail_decay_db_per_s * frame_ms / 1000,
                margin_db=residual_margin_db,
                mute=10 ** (RESIDUAL_MUTE_DB / 20),
            )
        self.delay_samples = self.frame_samples if self.suppressor is not None else 0
        self._span_frames = partitions  # echo of a frame can arrive this many frames later
        self._quiet_frames = partitions  # frames since the reference was last audible

    def learned(self) -> LearnedEcho | None:
        """What the pair learned, once worth remembering; None before."""
        if not self.canceller.worth_remembering:
            return None
        coefficients, variances, echo_left_db = self.canceller.learned()
        suppressor = self.suppressor
        return LearnedEcho(
            coefficients,
            variances,
            echo_left_db,
            suppressor.residual_db.copy() if suppressor else np.full(RESIDUAL_BANDS, RESIDUAL_INITIAL_DB),
            suppressor.coupling_db.copy() if suppressor else np.full(RESIDUAL_BANDS, COUPLING_INITIAL_DB),
        )

    def start_from(self, learned: LearnedEcho) -> None:
        """Start where a pair of this shape was (raises ValueError if it does not fit)."""
        bands = (RESIDUAL_BANDS,)
        if learned.residual_db.shape != bands or learned.coupling_db.shape != bands:
            raise ValueError(f"suppressor state of {learned.residual_db.shape} bands, expected {bands}")
        self.canceller.start_from(learned.coefficients, learned.variances, learned.echo_left_db)
        if self.suppressor is not None:
            self.suppressor.start_from(learned.residual_db, learned.coupling_db)

    def process(self, mic: Int16Array, reference: Int16Array) -> Int16Array:
        ref = to_float(reference)
        loud = float(np.dot(ref, ref)) > REFERENCE_FLOOR * len(ref)
        self._quiet_frames = 0 if loud else self._quiet_frames + 1
        path_changes = self.canceller.stats.path_changes
        error = self.canceller.process(to_float(mic), ref)
        if self.suppressor is not None:
            if self.canceller.stats.path_changes != path_changes:
                self.suppressor.relearn()
            active = self._quiet_frames < self._span_frames
            error = self.suppressor.process(
                error,
                self.canceller.echo_spectrum,
                self.canceller.reference_spectrum,
                active,
                self.canceller.uncertain_echo,
            )
        out: Int16Array = np.clip(np.rint(error * INT16_SCALE), -32768, 32767).astype(np.int16)
        return out
