import numpy as np
import pytest

from cryod.model.transfer_function import TransferFunction, TransferFunctionError


def test_gain_poles_and_time_constants():
    g1 = TransferFunction([340.91, 6.82], [165.41, 1.0])
    assert g1.dc_gain == pytest.approx(6.82)
    assert g1.time_constants_s == pytest.approx([165.41])
    assert g1.order == 1


@pytest.mark.parametrize("numerator, denominator, message", [
    ([1.0, 2.0, 3.0], [1.0, 1.0], "improper"),
    ([1.0], [0.0, 0.0], "zero"),
    ([1.0], [-26.48, 1.0], "stable"),
    ([1.0], [1.0, 0.0], "stable"),
    ([float("nan")], [1.0, 1.0], "finite"),
])
def test_refuses_unphysical(numerator, denominator, message):
    with pytest.raises(TransferFunctionError, match=message):
        TransferFunction(numerator, denominator)


def test_series_and_frequency_response():
    g1 = TransferFunction([340.91, 6.82], [165.41, 1.0])
    g2 = TransferFunction([1.0], [26.48, 1.0])
    product = g2 * g1
    omega = np.array([0.01, 0.3, 10.83])
    np.testing.assert_allclose(product.frequency_response(omega),
                               g1.frequency_response(omega) * g2.frequency_response(omega))
    # paper eq. (2): G1 G2 = (340.91 s + 6.82) / ((26.48 s + 1)(165.41 s + 1))
    np.testing.assert_allclose(product.denominator, np.polymul([26.48, 1.0], [165.41, 1.0]))


def test_time_scaling_keeps_gain_and_stretches_dynamics():
    g = TransferFunction([340.91, 6.82], [165.41, 1.0]) * TransferFunction([1.0], [26.48, 1.0])
    slower = g.time_scaled(1.3)
    assert slower.dc_gain == pytest.approx(g.dc_gain)
    assert slower.time_constants_s == pytest.approx([1.3 * 165.41, 1.3 * 26.48])
    assert slower.frequency_response(1.0) == pytest.approx(g.frequency_response(1.3))


@pytest.mark.parametrize("tf", [
    TransferFunction([2.0, 1.0], [3.0, 4.0, 1.0]),
    TransferFunction([1.0, 0.0, 2.0], [1.0, 0.4, 4.0]),            # complex poles, biproper
    TransferFunction([1.0], np.polymul([0.1, 1.0], [0.1, 1.0])),    # repeated pole
])
def test_modal_form_reproduces_frequency_response(tf):
    form = tf.modal_form()
    for omega in (0.0, 0.05, 1.0, 10.83, 300.0):
        s = 1j * omega
        modal = form.direct + np.sum(form.residues / (s - form.poles))
        assert modal == pytest.approx(tf.frequency_response(omega), rel=1e-6, abs=1e-12)
