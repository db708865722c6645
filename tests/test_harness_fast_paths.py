"""The in-process harness's per-step shortcuts against what they replace.

References: PursuerState's own constructor; numpy's `position + velocity * dt` (the expression
TargetModel.step used for straight flight, copied verbatim); a flight log row written by numpy's
each flight-log column's own definition (its source value's float64 bits).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core.messages import PursuerState, pursuer_state
from sitl_plant.world.target import Maneuver, TargetModel
from studies.closed_loop import FlightLog, _log_row
from tests.bitwise import assert_same

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite = st.floats(-1e6, 1e6, allow_nan=False)
vectors = st.lists(floats, min_size=3, max_size=3).map(np.array)


@given(floats, vectors, vectors)
def test_pursuer_state_builds_what_the_constructor_builds(time, position, velocity):
    built, constructed = pursuer_state(time, position, velocity), PursuerState(time, position, velocity)
    assert type(built) is PursuerState and "__post_init__" not in vars(PursuerState)
    assert list(vars(built)) == list(vars(constructed)) == [field.name for field in dataclasses.fields(PursuerState)]
    for name in vars(constructed):
        assert getattr(built, name) is getattr(constructed, name)
    with pytest.raises(dataclasses.FrozenInstanceError):
        built.time = 2.0


@given(vectors, vectors, st.floats(0.0, 10.0) | floats)
def test_straight_target_step_gives_numpys_bits(position, velocity, dt):
    target = TargetModel(position, velocity)
    with np.errstate(all="ignore"):
        expected = position + velocity * dt  # the replaced code, verbatim
    target.step(dt)
    assert_same(target.position, expected)
    assert target.position.dtype == np.float64 and target.position.shape == (3,)
    assert target.position is not position and target.velocity.tobytes() == velocity.tobytes()


@given(st.lists(finite, min_size=3, max_size=3), st.floats(1.0, 30.0), st.floats(0.001, 0.5))
def test_a_target_between_its_turns_steps_as_numpy_did(position, speed, dt):
    """Maneuvers scheduled but none active at the step: the straight path, numpy's bits."""
    velocity = np.array([speed, 0.5, -0.25])
    target = TargetModel(np.array(position), velocity, (Maneuver(100.0, 110.0, 2.0),))
    expected = np.array(position) + velocity * dt
    target.step(dt)
    assert_same(target.position, expected)


def _flight_output():
    """One PipelineOutput with every field the log reads, from a short flight (the IMM, the default estimator)."""
    from companion.assembly import build_pipeline
    from interfaces.scenario import SCENARIOS_DIR, load_scenario

    scenario, vehicle = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    pipeline = build_pipeline(scenario, vehicle, 0.5)
    from companion.core.messages import BearingMeasurement

    output = None
    for k in range(40):
        time = 0.02 * k
        pursuer = PursuerState(time, np.array([0.0, 0.0, -10.0]), np.zeros(3))
        bearing = BearingMeasurement(time, np.array([0.8, 0.6, 0.0]), pursuer.position) if k % 5 == 0 else None
        output = pipeline.step_all(time, pursuer, [bearing] if bearing else [])
    assert output.estimate is not None and output.health is not None and output.setpoint is not None
    return output, pipeline.estimator


def _expected_columns(time, position, velocity, rotation, target, output, estimator, bearings=()):
    """What each FlightLog column of one row must hold, by its definition (FlightLog._WIDTHS's comments)."""
    from studies.closed_loop import HEALTH_ACTION_CODES, HEALTH_REASON_BITS, TRACK_MODE_CODES, HealthState

    nan = math.nan
    estimate, setpoint, health = output.estimate, output.setpoint, output.health
    matrix = np.array(rotation, dtype=object).reshape(3, 3)
    columns = {"time": [time], "pursuer_position": list(position), "pursuer_velocity": list(velocity),
               "pursuer_forward": list(matrix[:, 0]), "pursuer_down_z": [matrix[2, 2]],
               "target_position": list(target.position), "target_velocity": list(target.velocity),
               "pursuer_rotation": list(rotation)}
    if estimate is not None:
        c = estimate.covariance
        columns |= {"estimate_position": list(estimate.position), "estimate_velocity": list(estimate.velocity),
                    "estimate_position_std": [estimate.position_std], "track_mode": [TRACK_MODE_CODES[output.mode]],
                    "bearing_age": [output.bearing_age],
                    "estimate_position_covariance": [c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2]],
                    "model_probabilities": list(getattr(estimator, "motion_probabilities", None) or [nan] * 3)}
    columns["command_acceleration"] = list(setpoint.acceleration) if setpoint is not None else [nan] * 3
    columns["thrust_normalized"] = [setpoint.thrust_normalized if setpoint is not None else nan]
    if output.observability is not None:
        columns["observability_log_det"] = [output.observability["log_det"]]
        columns["observability_min_eigenvalue"] = [output.observability["min_eigenvalue"]]
    if health is not None:
        columns |= {"health_suspect": [float(health.state is HealthState.SUSPECT)],
                    "health_reasons": [sum(HEALTH_REASON_BITS[r] for r in health.reasons)],
                    "health_nis_ratio": [health.nis_ratio], "health_relative_range_std": [health.relative_range_std],
                    "health_action": [HEALTH_ACTION_CODES[output.health_action]],
                    "process_noise_boost": [output.process_noise_boost],
                    "health_reinitialized": [float(output.health_reinitialized)]}
    own = [b for b in bearings if b.source == 0]
    if own:
        columns["bearing_direction"] = list(own[-1].direction)
    return {key: np.array(columns.get(key, [nan] * width), dtype=np.float64) for key, width in FlightLog._WIDTHS.items()}


def _bearing(direction, source=0):
    from companion.core.messages import BearingMeasurement

    return dataclasses.replace(BearingMeasurement(0.0, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
                               direction=np.array(direction, dtype=float), source=source)


@given(st.lists(floats, min_size=19, max_size=19), st.sampled_from(["full", "no estimate", "nothing yet"]),
       st.sampled_from([(), ("own",), ("own", "neighbour"), ("neighbour",)]))
def test_a_log_row_holds_each_column_by_its_definition(numbers, outputs, sources):
    """_log_row packs a row's floats as bytes: each column must hold its source's float64 bits (NaN payloads,
    signed zeros, infinities), with or without the estimate's numbers handed in, the last own bearing only."""
    output, estimator = _OUTPUT
    if outputs != "full":
        output = dataclasses.replace(output, estimate=None)
    if outputs == "nothing yet":
        output = dataclasses.replace(output, setpoint=None, observability=None, health=None)
    target = TargetModel(np.array(numbers[7:10]), np.array(numbers[4:7]))
    bearings = [_bearing(numbers[k:k + 3], 0 if kind == "own" else 2) for k, kind in zip((1, 13), sources)]
    arguments = (numbers[9], numbers[0:3], tuple(numbers[3:6]), tuple(numbers[10:19]), target, output, estimator)
    log = FlightLog(3)
    _log_row(log, *arguments, estimate_values=None, bearings=bearings)
    values = None if output.estimate is None else output.estimate.position.tolist() + output.estimate.velocity.tolist()
    _log_row(log, *arguments, estimate_values=values, bearings=bearings)
    expected = _expected_columns(*arguments, bearings)
    assert log.rows == 2 and log._table[0].tobytes() == log._table[1].tobytes()
    for key, column in log._data.items():
        assert column[0].tobytes() == expected[key].tobytes(), key
    assert np.isnan(log._table[2]).all()


def test_a_log_value_struct_refuses_goes_through_numpys_conversion():
    """A value that is not a float or int (here a string numpy reads as a number, and None, which numpy writes as
    NaN) takes numpy's conversion; what numpy refuses raises and leaves the row unwritten."""
    output, estimator = _OUTPUT
    target = TargetModel(np.zeros(3), np.ones(3))
    log = FlightLog(2)
    rotation = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, None)
    arguments = ("1.5", (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), rotation, target, output, estimator)
    _log_row(log, *arguments)
    assert log._table[0, 0] == 1.5 and math.isnan(log._data["pursuer_down_z"][0, 0])
    assert log._data["pursuer_forward"][0].tolist() == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError):
        _log_row(log, "not a number", *arguments[1:])
    assert log.rows == 1 and np.isnan(log._table[1]).all()


_OUTPUT = _flight_output()


HOME = (47.397742, 8.545594, 488.0)


def _payloads(data):
    """A stream of target-fix payloads: plausible ones, off-track, stale, from someone else, in another epoch, and
    each of the link model's corruptions of them (sitl_plant.world.link_faults.corrupt_payload), or raw bytes."""
    from interfaces import link_schema
    from interfaces.scenario import CORRUPT_KINDS
    from sitl_plant.world.link_faults import corrupt_payload

    stream = []
    for k in range(data.draw(st.integers(1, 12))):
        seq = data.draw(st.sampled_from([k, k, k - 3, k + 2**40]))
        sender = data.draw(st.sampled_from(["target-1", "target-1", "impostor-1"]))
        offset = data.draw(st.sampled_from([0.0, 0.0, 3.0, 40.0]))
        fix = link_schema.TargetFix(sender, max(seq, 0), 0.2 * k, "ned", (10.0 + 2.0 * k + offset, -5.0, -20.0),
                                    (10.0, 0.0, 0.0), data.draw(st.sampled_from([7, 7, 8])))
        payload = link_schema.encode_target_fix(fix)
        how = data.draw(st.sampled_from(["as sent", *CORRUPT_KINDS, "bytes"]))
        if how == "bytes":
            payload = data.draw(st.binary(max_size=64))
        elif how != "as sent":
            payload, _ = corrupt_payload(payload, how, np.array(data.draw(st.lists(st.floats(0.0, 0.999), min_size=4,
                                                                                   max_size=4))))
        stream.append((0.2 * k + data.draw(st.sampled_from([0.0, 0.0, -5.0, 10.0])), payload))  # late, early
    return stream


def _check_in_one_piece(intake, payload, now=None, agrees=None):
    """A fix intake's check in one piece, from the public parts: the link schema's decoder (a refusal counted by the
    validator), the fix's position in NED, then the validator's check."""
    from companion.core.fix_validator import FixRejected
    from interfaces import link_schema

    self = intake
    try:
        fix = link_schema.decode_target_fix(payload)
    except link_schema.PayloadError as error:
        self.validator.reject(error.reason)
        raise FixRejected(error.reason, error.detail) from None
    position = link_schema.fix_to_ned(fix, self.home)
    return fix, self.validator.check(fix.sender, fix.seq, fix.stamp, position, epoch=fix.epoch, now=now,
                                     agrees=agrees)


@given(st.data())
def test_decode_then_check_decoded_is_check(data):
    """The in-process link decodes a payload once (FixIntake.decode, then check_decoded): the same fixes, positions
    and refusals, counted the same, as decoding and checking in one piece (twin intakes fed the same stream; the
    reference is `_check_in_one_piece`, built from the schema's decoder and the validator), and check is still that."""
    from companion.core.fix_validator import FixRejected, FixValidator
    from companion.fix_intake import FixIntake

    def outcome(check, *args, **keywords):
        try:
            fix, position = check(*args, **keywords)
        except FixRejected as error:
            return "refused", error.reason, str(error)
        return "accepted", fix, position.tobytes()

    whole, split, current = (FixIntake(FixValidator("target-1", silence=1.0), HOME) for _ in range(3))

    def decoded_once(payload, now):
        return split.check_decoded(split.decode(payload), now=now)

    for now, payload in _payloads(data):
        expected = outcome(_check_in_one_piece, whole, payload, now=now)
        assert outcome(decoded_once, payload, now) == expected
        assert outcome(current.check, payload, now=now) == expected
    for intake in (split, current):
        assert (intake.validator.accepted, dict(intake.validator.rejected), intake.validator.reanchors) == (
            whole.validator.accepted, dict(whole.validator.rejected), whole.validator.reanchors)


def _setpoint_matrices():
    """Rotations (every Shepperd branch: small angles, half turns about each axis), perturbed ones near the 1e-6
    tolerance, NaN, infinity, reflections, and wrong shapes."""
    from scipy.spatial.transform import Rotation

    rotations = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
        lambda q: sum(x * x for x in q) > 1e-3).map(lambda q: Rotation.from_quat(q).as_matrix())
    half_turns = st.sampled_from([np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])

    def spoil(matrix, how, entry, amount):
        flat = matrix.reshape(-1).copy()
        if how == "perturbed":
            flat[entry] += amount
        elif how == "nan":
            flat[entry] = math.nan
        elif how == "infinite":
            flat[entry] = math.inf
        elif how == "reflection":
            flat[entry % 3::3] *= -1.0
        elif how == "shape":
            return flat[:6].reshape(2, 3)
        return flat.reshape(3, 3)

    return st.builds(spoil, rotations | half_turns,
                     st.sampled_from(["rotation", "rotation", "perturbed", "nan", "infinite", "reflection", "shape"]),
                     st.integers(0, 8), st.floats(-2e-6, 2e-6))


def _outcome_of(function, *args):
    try:
        return function(*args)
    except ValueError as error:
        return ValueError, str(error)


@settings(max_examples=300, deadline=None)
@given(_setpoint_matrices())
def test_the_vehicle_takes_a_proper_rotation_and_refuses_the_rest(matrix):
    """AttitudeThrustVehicle.set_attitude_target (kernels.setpoint_quaternion, compiled when numba is there): a
    (3, 3) rotation (R^T R = I and det R = +1 within 1e-6) is held as a unit quaternion of that rotation (scipy's
    Rotation of it is the matrix); another shape, a non-finite entry or a matrix off by more than 3e-6 is refused
    with a ValueError that says why; the compiled kernel and its plain-Python function decide alike."""
    from scipy.spatial.transform import Rotation

    from sitl_plant.vehicle import kernels
    from sitl_plant.vehicle.attitude_control import AttitudeThrustVehicle
    from sitl_plant.vehicle.params import table1_params

    vehicle = AttitudeThrustVehicle(table1_params(), rng=0)
    if matrix.shape != (3, 3):
        with pytest.raises(ValueError, match="must be a \\(3, 3\\) array"):
            vehicle.set_attitude_target(matrix, 10.0)
        return
    finite = bool(np.isfinite(matrix).all())
    deviation = (max(float(np.abs(matrix.T @ matrix - np.eye(3)).max()), abs(float(np.linalg.det(matrix)) - 1.0))
                 if finite else math.inf)
    entries = matrix.ravel().tolist()
    compiled, plain = kernels.setpoint_quaternion(*entries), kernels.setpoint_quaternion.py_func(*entries)
    assert compiled[0] is plain[0]
    np.testing.assert_allclose(compiled[1:], plain[1:], rtol=0.0, atol=1e-15)
    if deviation > 3e-6:
        with pytest.raises(ValueError, match="is not a proper rotation matrix"):
            vehicle.set_attitude_target(matrix, 10.0)
        return
    if deviation > 1e-7:  # near the tolerance: either decision is the check's own
        return
    vehicle.set_attitude_target(matrix, 10.0)
    w, x, y, z = vehicle._qd
    assert vehicle._thrust == 10.0 and math.isclose(w * w + x * x + y * y + z * z, 1.0, rel_tol=1e-6)
    np.testing.assert_allclose(Rotation.from_quat([x, y, z, w]).as_matrix(), matrix, rtol=0.0, atol=1e-6)


_NUMBERS = st.floats(-1e7, 1e7, allow_nan=False)


@given(st.text(min_size=1, max_size=12), st.integers(0, 2**62), st.floats(0.0, 1e6), st.lists(_NUMBERS, min_size=3, max_size=3),
       st.lists(_NUMBERS, min_size=3, max_size=3), st.integers(0, 2**31 - 1))
def test_a_decoded_fix_is_the_fix_it_encodes(sender, seq, stamp, position, velocity, epoch):
    """What LinkFaults.offer's `fix` rests on: decode_target_fix(encode_target_fix(fix)) is fix, field for field and
    bit for bit (signed zeros too) for the fixes the in-process link offers (NED, finite, with velocity and epoch)."""
    from interfaces.link_schema import PayloadError, TargetFix, decode_target_fix, encode_target_fix

    fix = TargetFix(sender, seq, stamp, "ned", np.array(position), np.array(velocity), epoch)
    try:
        payload = encode_target_fix(fix)
    except PayloadError:
        return  # a fix the encoder refuses never reaches the link model (the flight stops first)
    decoded = decode_target_fix(payload)
    assert repr(decoded) == repr(fix)
    for name in ("stamp", "position", "velocity"):
        assert np.asarray(getattr(decoded, name)).tobytes() == np.asarray(getattr(fix, name)).tobytes()
    assert type(decoded.seq) is type(fix.seq) is int and type(decoded.epoch) is int


@pytest.mark.parametrize("pattern", ["future_seq", "future_stamp", "replay", "target_restart", "spoof_burst",
                                     "spoof_steady", "spoof_close_sniffed", "impostor", "corrupt", "reorder_duplicate",
                                     "target_restart+spoof_steady_sniffed", "target_restart+impostor"])
def test_link_faults_given_the_fix_deliver_what_they_deliver_decoding_it(pattern):
    """LinkFaults.offer(..., fix): the same deliveries, events and counters as offer without it (which decodes the
    payload), for every attack and the impostor, over a 60 s stream at 5 Hz."""
    from interfaces.link_schema import TargetFix, encode_target_fix
    from interfaces.scenario import SCENARIOS_DIR, load_scenario
    from sitl_plant.world.link_faults import LinkFaults, fault_rng
    from studies.campaign import PATTERNS, with_faults

    scenario, _ = load_scenario(SCENARIOS_DIR / "constant_velocity.toml")
    overrides = {key: value for name in pattern.split("+") for key, value in PATTERNS[name][0].items()}
    config = with_faults(scenario, overrides).faults
    given_fix, decoding = (LinkFaults(config, fault_rng(config, 3)) for _ in range(2))
    for k in range(300):
        now = 0.2 * k
        fix = TargetFix("target-1", k, now, "ned", (10.0 + 0.6 * k, 5.0 - 0.8 * k, -20.0), (3.0, -4.0, 0.0), 4242)
        payload = encode_target_fix(fix)
        given_fix.offer(now, payload, now, fix)
        decoding.offer(now, payload, now)
        for tick in (now, now + 0.1):
            assert given_fix.due(tick) == decoding.due(tick), (k, tick)
    assert given_fix.events == decoding.events and given_fix.counters == decoding.counters
    assert any(event.kind.startswith(("attack", "impostor", "target_restart", "corrupt", "reorder")) for event in decoding.events)
