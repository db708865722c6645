"""The in-process harness's per-step shortcuts against what they replace.

References: PursuerState's own constructor; numpy's `position + velocity * dt` (the expression
TargetModel.step used for straight flight, copied verbatim); a flight log row written by numpy's
conversion of the same list (`table[row] = values`, what _log_row did before it packed bytes).
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


def _old_log_row(table, row, time, position, velocity, forward, down_z, target, output, estimator=None):
    """studies.closed_loop._log_row as of 1c852b6, verbatim but for writing into `table` (numpy's conversion)."""
    from studies.closed_loop import (
        _NAN3,
        HEALTH_ACTION_CODES,
        HEALTH_REASON_BITS,
        TRACK_MODE_CODES,
        HealthState,
    )

    estimate, setpoint = output.estimate, output.setpoint
    nan = math.nan
    values = [time, *position, *velocity, *forward, down_z, *target.position.tolist(), *target.velocity.tolist()]
    if estimate is not None:
        values += [*estimate.position.tolist(), *estimate.velocity.tolist(), estimate.position_std]
    else:
        values += [nan] * 7
    if setpoint is not None:
        values += [*setpoint.acceleration.tolist(), setpoint.thrust_normalized]
    else:
        values += [nan] * 4
    if estimate is not None:
        values += [TRACK_MODE_CODES[output.mode], output.bearing_age]
    else:
        values += [nan, nan]
    observability = output.observability
    if observability is not None:
        values += [observability["log_det"], observability["min_eigenvalue"]]
    else:
        values += [nan, nan]
    health = output.health
    if health is not None:
        reasons = health.reasons
        values += [float(health.state is HealthState.SUSPECT), sum(HEALTH_REASON_BITS[reason] for reason in reasons) if reasons else 0,
                   health.nis_ratio, health.relative_range_std, HEALTH_ACTION_CODES[output.health_action],
                   output.process_noise_boost, float(output.health_reinitialized)]
    else:
        values += [nan] * 7
    motion = getattr(estimator, "motion_probabilities", None) if estimate is not None else None
    values += _NAN3 if motion is None else motion
    table[row] = values


@given(st.lists(floats, min_size=10, max_size=10), st.sampled_from(["full", "no estimate", "nothing yet"]))
def test_a_log_row_holds_the_bits_the_old_row_held(numbers, outputs):
    """_log_row packs a row's floats as bytes: the table must hold what numpy's conversion of the old row held
    (NaN payloads, signed zeros, infinities), with or without the estimate's numbers handed in."""
    output, estimator = _OUTPUT
    if outputs != "full":
        output = dataclasses.replace(output, estimate=None)
    if outputs == "nothing yet":
        output = dataclasses.replace(output, setpoint=None, observability=None, health=None)
    target = TargetModel(np.array(numbers[7:10]), np.array(numbers[4:7]))
    arguments = (numbers[9], numbers[0:3], tuple(numbers[3:6]), numbers[6:9], numbers[0], target, output, estimator)
    log = FlightLog(3)
    _log_row(log, *arguments)
    values = None if output.estimate is None else output.estimate.position.tolist() + output.estimate.velocity.tolist()
    _log_row(log, *arguments, values)
    reference = np.full((1, FlightLog._WIDTH), 7.0)
    _old_log_row(reference, 0, *arguments)
    assert log.rows == 2 and log._table[0].tobytes() == log._table[1].tobytes() == reference[0].tobytes()
    assert np.isnan(log._table[2]).all()


def test_a_log_value_struct_refuses_goes_through_numpys_conversion():
    """A value that is not a float or int (here a string numpy reads as a number, and None, which numpy writes as
    NaN) takes numpy's conversion, as every row did before; what numpy refuses raises as before."""
    output, estimator = _OUTPUT
    target = TargetModel(np.zeros(3), np.ones(3))
    log, reference = FlightLog(2), np.full((1, FlightLog._WIDTH), 7.0)
    arguments = ("1.5", (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (1.0, 0.0, 0.0), None, target, output, estimator)
    _log_row(log, *arguments)
    _old_log_row(reference, 0, *arguments)
    assert log._table[0, 0] == 1.5 and math.isnan(log._table[0, 10])
    assert log._table[0].tobytes() == reference[0].tobytes()
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


def _old_check(intake, payload, now=None, agrees=None):
    """companion.fix_intake.FixIntake.check as of 1c852b6 (before it was split in decode and check_decoded), verbatim."""
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
    and refusals, counted the same, as FixIntake.check did on the payload (twin intakes fed the same stream; the
    reference is the old check, verbatim), and check is still that."""
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
        expected = outcome(_old_check, whole, payload, now=now)
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
