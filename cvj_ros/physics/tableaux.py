"""Coefficients of the methods whose compiled steppers take them as arguments (RODAS3,
RODAS4, RODAS5P, DOP853), importable without scipy.integrate / scipy.linalg: the compiled path
(kernel/stepper.py) reads them from here, so a `cvj-sim simulate --method rosenbrock` or
a coupling node does not pay ~0.3-0.5 s of scipy imports for a few dozen numbers
(docs/solvers.md "Start-up"). solvers.py (the Python steppers) uses the same functions.
"""
from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np

RODAS5P_ORDER = 4   # embedded order of RODAS5P -> controller exponent 1/5
RODAS4_ORDER = 3    # embedded order of RODAS4 -> controller exponent 1/4
RODAS3_ORDER = 2    # embedded order of RODAS3 -> controller exponent 1/3
RODAS_FAC_MAX = 6.0  # largest step increase of all three (Hairer's RODAS: FAC2 = 6)


def rodas3_tableau() -> dict:
    """RODAS3 (Sandu, Verwer, Blom, Spee, Carmichael, Potra, Atmos. Environ. 31 (1997) 3459,
    "Benchmarking stiff ODE solvers for atmospheric chemistry problems II: Rosenbrock
    solvers"; the coefficients as KPP's Rosenbrock integrator lists them) in the K form of
    :func:`rodas4_tableau`: 4 stages, order 3, embedded order 2, stiffly accurate
    (y_new = stage 4's argument + K_4), L-stable; err = K_4. Stage 2 evaluates f at
    (t, y) like stage 1 (alpha_2 = 0, no A terms): the steppers reuse f(t, y) there
    (KPP's ros_NewF(2) = false), so a step costs 3 fev, 1 Jacobian, 1 LU, 4 solves.
    """
    A = np.zeros((4, 4))
    C = np.zeros((4, 4))
    A[2, :2] = [2.0, 0.0]
    A[3, :3] = [2.0, 0.0, 1.0]
    C[1, 0] = 4.0
    C[2, :2] = [1.0, -1.0]
    C[3, :3] = [1.0, -1.0, -8.0 / 3.0]
    M = np.array([2.0, 0.0, 1.0, 1.0])
    E = np.array([0.0, 0.0, 0.0, 1.0])
    alpha = np.array([0.0, 0.0, 1.0, 1.0])
    gamma_sum = np.array([0.5, 1.5, 0.0, 0.0])
    return dict(gamma=0.5, A=A, C=C, M=M, E=E, alpha=alpha, gamma_sum=gamma_sum)


def rodas4_tableau() -> dict:
    """RODAS4 in the 'K' form used by Hairer's RODAS code (Hairer & Wanner II, sec.
    IV.7 / code rodas.f, METH=1):
        (I/(h g) - J) K_i = f(t + alpha_i h, y + sum_j A_ij K_j) + sum_j C_ij/h K_j + h gamma_i f_t
        y_new = y + sum_j M_j K_j,   err = K_6.
    """
    A = np.zeros((6, 6))
    C = np.zeros((6, 6))
    A[1, 0] = 1.544
    A[2, :2] = [0.9466785280815826, 0.2557011698983284]
    A[3, :3] = [3.314825187068521, 2.896124015972201, 0.9986419139977817]
    A[4, :4] = [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895]
    A[5, :5] = [*A[4, :4], 1.0]
    C[1, 0] = -5.6688
    C[2, :2] = [-2.430093356833875, -0.2063599157091915]
    C[3, :3] = [-0.1073529058151375, -9.594562251023355, -20.47028614809616]
    C[4, :4] = [7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616]
    C[5, :5] = [8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
                -6.058818238834054]
    M = np.array([*A[4, :4], 1.0, 1.0])
    E = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    alpha = np.array([0.0, 0.386, 0.21, 0.63, 1.0, 1.0])
    gamma_sum = np.array([0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0])
    return dict(gamma=0.25, A=A, C=C, M=M, E=E, alpha=alpha, gamma_sum=gamma_sum)


def rodas5p_tableau() -> dict:
    """RODAS5P (Steinebach, BIT Numer. Math. 2023, "Construction of Rosenbrock-Wanner
    methods for DAEs with improved order"; coefficients as in OrdinaryDiffEq.jl) in
    the same K form: 8 stages, order 5(4), stiffly accurate, L-stable; stages 6-8
    evaluate at c = 1 and each adds the previous K, y_new = Y_8 + K_8, err = K_8.
    """
    A = np.zeros((8, 8))
    C = np.zeros((8, 8))
    A[1, 0] = 3.0
    A[2, :2] = [2.849394379747939, 0.45842242204463923]
    A[3, :3] = [-6.954028509809101, 2.489845061869568, -10.358996098473584]
    A[4, :4] = [2.8029986275628964, 0.5072464736228206, -0.3988312541770524,
                -0.04721187230404641]
    A[5, :5] = [-7.502846399306121, 2.561846144803919, -11.627539656261098,
                -0.18268767659942256, 0.030198172008377946]
    A[6, :6] = [*A[5, :5], 1.0]
    A[7, :7] = [*A[5, :5], 1.0, 1.0]
    C[1, 0] = -14.155112264123755
    C[2, :2] = [-17.97296035885952, -2.859693295451294]
    C[3, :3] = [147.12150275711716, -1.41221402718213, 71.68940251302358]
    C[4, :4] = [165.43517024871676, -0.4592823456491126, 42.90938336958603, -5.961986721573306]
    C[5, :5] = [24.854864614690072, -3.0009227002832186, 47.4931110020768, 5.5814197821558125,
                -0.6610691825249471]
    C[6, :6] = [30.91273214028599, -3.1208243349937974, 77.79954646070892, 34.28646028294783,
                -19.097331116725623, -28.087943162872662]
    C[7, :7] = [37.80277123390563, -3.2571969029072276, 112.26918849496327, 66.9347231244047,
                -40.06618937091002, -54.66780262877968, -9.48861652309627]
    M = np.array([*A[5, :5], 1.0, 1.0, 1.0])
    E = np.zeros(8)
    E[7] = 1.0
    alpha = np.array([0.0, 0.6358126895828704, 0.4095798393397535, 0.9769306725060716,
                      0.4288403609558664, 1.0, 1.0, 1.0])
    gamma_sum = np.array([0.21193756319429014, -0.42387512638858027, -0.3384627126235924,
                          1.8046452872882734, 2.325825639765069, 0.0, 0.0, 0.0])
    # continuous extension: y(x) = (1-x) y0 + x (y1 + (1-x) (D1 + x (D2 + x D3))), D = H K
    H = np.array([
        [25.948786856663858, -2.5579724845846235, 10.433815404888879, -2.3679251022685204,
         0.524948541321073, 1.1241088310450404, 0.4272876194431874, -0.17202221070155493],
        [-9.91568850695171, -0.9689944594115154, 3.0438037242978453, -24.495224566215796,
         20.176138334709044, 15.98066361424651, -6.789040303419874, -6.710236069923372],
        [11.419903575922262, 2.8879645146136994, 72.92137995996029, 80.12511834622643,
         -52.072871366152654, -59.78993625266729, -0.15582684282751913, 4.883087185713722]])
    return dict(gamma=0.21193756319429014, A=A, C=C, M=M, E=E, alpha=alpha,
                gamma_sum=gamma_sum, H=H)


#: compiled Rosenbrock method -> (tableau, embedded order); all use RODAS_FAC_MAX
ROSENBROCK_TABLEAUX = {'rosenbrock': (rodas5p_tableau, RODAS5P_ORDER),
                       'rodas4': (rodas4_tableau, RODAS4_ORDER),
                       'rodas3': (rodas3_tableau, RODAS3_ORDER)}


@functools.lru_cache(maxsize=1)
def dop853_coefficients() -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """((C, A, B, E5, E3), (D, A_EXTRA, C_EXTRA)) of ``scipy.integrate.DOP853`` (Hairer's
    DOP853 coefficients), as that class slices them from scipy's coefficient module.

    The module (``scipy/integrate/_ivp/dop853_coefficients.py``, numpy only) is executed
    from its file: importing it by name would run ``scipy.integrate``'s package
    ``__init__`` (all of scipy.integrate, with scipy.linalg and scipy.sparse). If the file
    is not where scipy keeps it, the class itself is imported. The arrays are read-only
    views; callers copy them (``np.array``)."""
    coef = None
    spec = importlib.util.find_spec('scipy')
    if spec is not None and spec.submodule_search_locations:
        path = Path(list(spec.submodule_search_locations)[0]) / 'integrate' / '_ivp' \
            / 'dop853_coefficients.py'
        if path.is_file():
            file_spec = importlib.util.spec_from_file_location(
                'cvj_ros.physics._scipy_dop853_coefficients', path)
            if file_spec is not None and file_spec.loader is not None:
                coef = importlib.util.module_from_spec(file_spec)
                file_spec.loader.exec_module(coef)
    if coef is None:
        from scipy.integrate import DOP853
        return ((DOP853.C, DOP853.A, DOP853.B, DOP853.E5, DOP853.E3),
                (DOP853.D, DOP853.A_EXTRA, DOP853.C_EXTRA))
    n = coef.N_STAGES   # as scipy.integrate._ivp.rk.DOP853
    return ((coef.C[:n], coef.A[:n, :n], coef.B, coef.E5, coef.E3),
            (coef.D, coef.A[n + 1:], coef.C[n + 1:]))
