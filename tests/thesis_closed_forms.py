"""Test oracle: the thesis's closed-form kinematics and dynamics of its arm.

Pure numpy (no pydrake), written from Kiguchi (1993), Appendix C
("Manipulator kinematics": C1 forward kinematics, C2 Jacobian and its
derivative) and Appendix D ("Manipulator dynamics": recursive Newton-Euler,
sections D1-D6). The closed forms of M(q) and h(q, qdot) are Appendix D's
joint torques D4-4, D5-4, D6-4 with the forward quantities D1-D3 substituted,
collected by joint acceleration (M) and by squared joint rates (h); they are
written with the same grouped terms ``ta``, ``tb``, ``tc`` that the thesis's
Appendix E code uses for ``M[i][j]`` and ``OMG[i]``.

Conventions (thesis Appendix C, D-H table; Appendix D's link data):
- three revolute joints about z in the horizontal plane; gravity is along z,
  so it never enters a joint torque (the thesis carries ``-g`` in the z rows
  of D1-3..D3-5; those rows only feed the x/y moments n_x, n_y, which no motor
  resists, so g is dropped here);
- q = (theta_1, theta_2, theta_3); link i runs from joint i to joint i+1 (link
  3 to the tool tip), its D-H frame i sits at its distal end;
- S_ix is the COM offset measured from that distal end along the link, so the
  COM lies at ``a_i + S_ix`` from joint i; Izz_i is about the COM.

"Line N" in comments below is a line of
``/work/shared/thesis/kiguchi-1993-thesis.txt`` (an OCR scan). Where a printed
term is damaged, the comment says what the OCR shows and what is used here;
every function is checked against an independent Lagrangian / finite
difference / MultibodyPlant computation (see the tests that import this).

Rates: w1 = q1d, w12 = q1d + q2d, w123 = q1d + q2d + q3d (the absolute
angular velocities of links 1, 2, 3; Appendix D's Omega_1..3, D1-1..D3-1).
"""

import numpy as np

#: Link data as printed at the end of Appendix D (lines 1404-1409); identical
#: to drake_contact.plant.arm (not imported: that module pulls in
#: pydrake, and the oracle must stay independent of it).
LINK_LENGTHS = (0.2207, 0.1603, 0.1508)          # a_i (m)
LINK_MASSES = (12.88, 5.95, 0.44)                # m_i (kg)
LINK_COM_OFFSETS = (-0.0476, -0.0619, -0.0918)   # S_ix (m), from distal end
LINK_IZZ = (0.138841, 0.039523, 1.339e-3)        # I_izz about COM (kg m^2)


def _q3(v, name):
    v = np.asarray(v, dtype=float).reshape(-1)
    if v.shape != (3,):
        raise ValueError(f"{name} must have 3 entries, got shape {v.shape}")
    return v


def forward_kinematics(q, lengths=LINK_LENGTHS):
    """Tip pose [x, y, phi] (m, m, rad).

    Appendix C1: the position column of T_3 = A_1 A_2 A_3, eq. (1-3)
    (restated at the top of C2), and phi from equating T_3 with the
    task-space form (1-4): theta_1 + theta_2 + theta_3 = phi, eq. (1-7).
        x = a1 C1 + a2 C12 + a3 C123,  y = a1 S1 + a2 S12 + a3 S123.
    """
    q = _q3(q, "q")
    a1, a2, a3 = lengths
    q12, q123 = q[0] + q[1], q[0] + q[1] + q[2]
    return np.array([
        a1 * np.cos(q[0]) + a2 * np.cos(q12) + a3 * np.cos(q123),
        a1 * np.sin(q[0]) + a2 * np.sin(q12) + a3 * np.sin(q123),
        q123,
    ])


def jacobian(q, lengths=LINK_LENGTHS):
    """J(q) = d[x, y, phi]/dq, 3x3, Appendix C2 eq. (2-1) (printed correctly)."""
    q = _q3(q, "q")
    a1, a2, a3 = lengths
    q12, q123 = q[0] + q[1], q[0] + q[1] + q[2]
    s1, s12, s123 = np.sin(q[0]), np.sin(q12), np.sin(q123)
    c1, c12, c123 = np.cos(q[0]), np.cos(q12), np.cos(q123)
    return np.array([
        [-a3 * s123 - a2 * s12 - a1 * s1, -a3 * s123 - a2 * s12, -a3 * s123],
        [a3 * c123 + a2 * c12 + a1 * c1, a3 * c123 + a2 * c12, a3 * c123],
        [1.0, 1.0, 1.0],
    ])


def jacobian_derivative(q, qdot, lengths=LINK_LENGTHS):
    """dJ/dt (3x3), Appendix C2 eq. (2-3), with its missing rate factors.

    OCR/print damage, eq. (2-3), line 1176: the printed matrix is
        [[-a3 C123 - a2 C12 - a1 C1, -a3 C123 - a2 C12, -a3 C123],
         [-a3 S123 - a2 S12 - a1 S1, -a3 S123 - a2 S12, -a3 S123],
         [0, 0, 0]]
    i.e. the derivative of each term of (2-1) with respect to its own angle
    but without that angle's rate. d/dt(a3 S123) = a3 C123 * w123, etc., so
    each term is multiplied here by its cumulative rate (a1 terms by w1, a2
    terms by w12, a3 terms by w123):
        Jdot = [[-a3 C123 w123 - a2 C12 w12 - a1 C1 w1, -a3 C123 w123 - a2 C12 w12, -a3 C123 w123],
                [-a3 S123 w123 - a2 S12 w12 - a1 S1 w1, -a3 S123 w123 - a2 S12 w12, -a3 S123 w123],
                [0, 0, 0]].
    (Appendix E, lines 1967-1972 and 2008-2010, uses the printed matrix and
    forms JD * qdot, which is linear in qdot: not the true Jdot qdot.)
    """
    q, qdot = _q3(q, "q"), _q3(qdot, "qdot")
    a1, a2, a3 = lengths
    q12, q123 = q[0] + q[1], q[0] + q[1] + q[2]
    w1, w12, w123 = qdot[0], qdot[0] + qdot[1], qdot.sum()
    # Per-link terms with their rates.
    cx1, cx2, cx3 = a1 * np.cos(q[0]) * w1, a2 * np.cos(q12) * w12, a3 * np.cos(q123) * w123
    sy1, sy2, sy3 = a1 * np.sin(q[0]) * w1, a2 * np.sin(q12) * w12, a3 * np.sin(q123) * w123
    return np.array([
        [-cx3 - cx2 - cx1, -cx3 - cx2, -cx3],
        [-sy3 - sy2 - sy1, -sy3 - sy2, -sy3],
        [0.0, 0.0, 0.0],
    ])


def jdot_qdot(q, qdot, lengths=LINK_LENGTHS):
    """True Jdot(q, qdot) @ qdot (3-vector): Appendix C2 eq. (2-3), repaired
    as in :func:`jacobian_derivative`, times qdot. In closed form
        [-(a1 C1 w1^2 + a2 C12 w12^2 + a3 C123 w123^2),
         -(a1 S1 w1^2 + a2 S12 w12^2 + a3 S123 w123^2),
         0].
    Quadratic in qdot, unlike Appendix E's ``JD * qdot`` (lines 2008-2010).
    """
    return jacobian_derivative(q, qdot, lengths) @ _q3(qdot, "qdot")


def _grouped_terms(q, lengths, com_offsets):
    """The grouped terms of Appendix E's M and OMG (lines 1974-1976), and the
    COM distances L_i = a_i + S_ix (Appendix D's Q_i, D4-2, D5-2, D6-2).

    ta, -tb: x and y (frame 3) of the vector from joint 1 to COM 3;
    tc, -a1 S2: x and y (frame 2) of the vector from joint 1 to COM 2.
    """
    q = _q3(q, "q")
    a1, a2, a3 = lengths
    L1, L2, L3 = (a + s for a, s in zip(lengths, com_offsets))
    s2, c2 = np.sin(q[1]), np.cos(q[1])
    s3, c3 = np.sin(q[2]), np.cos(q[2])
    s23, c23 = np.sin(q[1] + q[2]), np.cos(q[1] + q[2])
    ta = a2 * c3 + a1 * c23 + L3      # line 1974: ta = a2*c3+a1*c23+a3+S3x
    tb = a2 * s3 + a1 * s23           # line 1975: tb = a2*s3+a1*s23
    tc = a2 + a1 * c2 + com_offsets[1]  # line 1976: tc = a2+a1*c2+S2x
    return dict(a1=a1, a2=a2, a3=a3, L1=L1, L2=L2, L3=L3, s2=s2, c2=c2,
                s3=s3, c3=c3, s23=s23, c23=c23, ta=ta, tb=tb, tc=tc)


def mass_matrix(q, masses=LINK_MASSES, izz=LINK_IZZ, lengths=LINK_LENGTHS,
                com_offsets=LINK_COM_OFFSETS):
    """Joint-space inertia matrix M(q), 3x3 symmetric.

    Appendix D: M[i, j] is the coefficient of theta_j'' in the motor torque
    tau_i of D6-4 (i = 1), D5-4 (i = 2), D4-4 (i = 3), after substituting the
    effective forces/torques D1-5/6, D2-5/6, D3-5/6 (L_i = a_i + S_ix):
        tau_3 = L3 F3y + I3 w123'',                             (D4-4)
        tau_2 = tau_3 + a2 (F3x S3 + F3y C3) + L2 F2y + I2 w12'', (D5-4)
        tau_1 = tau_2 + a1 (f2x S2 + f2y C2) + L1 F1y + I1 w1''.  (D6-4)
    Collected, in the grouped form of Appendix E (lines 1974-1987):
        M11 = I1+I2+I3 + m3 (ta^2 + tb^2) + m2 (tc^2 + a1^2 S2^2) + m1 L1^2
        M12 = I2+I3 + m3 (ta (a2 C3 + L3) + a2 S3 tb) + m2 L2 tc
        M13 = I3 + m3 L3 ta
        M22 = I2+I3 + m3 ((a2 C3 + L3)^2 + a2^2 S3^2) + m2 L2^2
        M23 = I3 + m3 L3 (a2 C3 + L3)
        M33 = I3 + m3 L3^2,     M symmetric.

    OCR repairs in Appendix D used to derive this:
    - D2-4 line 1263: V2_y is reprinted with "- a_2 (th1''+th2'')"; D2-3
      (line 1256) has "+ a_2 (...)", which is correct; "+" used.
    - D2-4 line 1265 and D2-5 lines 1271-1272: "(a_2 + S_{1x})" / "(a_2 + S_1 x)";
      the COM of link 2 is at a_2 + S_2x (as D5-3 uses); S_2x used.
    - D5-2 line 1361: Q_2 = "a_2 - S_2 x" and D6-2 line 1383: Q_1 = "a_1 - S_1x";
      D5-3/D6-3 (and D4-2 for link 3) use a_i + S_ix; "+" used.
    - D4-1 line 1337: "[Rot4]{f_0}" is the tip force f_g (= 0), D4-3 line
      1347: "I_{3z}" is I_3zz; D3-6 line 1316: "[I_3]{Omega_3''} +
      [Dev Omega_3][I_3]{Omega_3'}" is Omega_3' and Omega_3 (as in D1-6,
      D2-6; the printed result is right).
    OCR repairs of the Appendix E M[][] (structure only; values derived above):
    - line 1977: "11zz" is l1zz (I_1zz);
    - line 1978: "m1*(a1+S1x)*(a1*S1x)" is m1*(a1+S1x)*(a1+S1x) = m1 L1^2;
    - line 1981: "m3*a2*c3*(a1*s23+a2*s3)" is m3*a2*s3*tb (as in M[0][1],
      line 1979; M is symmetric);
    - line 1986: M[2][1] "l3zz+m3*(a3+S3x)*(a3+S3x)+m3*a2*c3" lacks the
      factor (a3+S3x) on the last term: m3*(a3+S3x)*(a2*c3+a3+S3x) = M[1][2].
    """
    m1, m2, m3 = masses
    I1, I2, I3 = izz
    g = _grouped_terms(q, lengths, com_offsets)
    a1, a2 = g["a1"], g["a2"]
    L1, L2, L3 = g["L1"], g["L2"], g["L3"]
    s2, s3, c3 = g["s2"], g["s3"], g["c3"]
    ta, tb, tc = g["ta"], g["tb"], g["tc"]
    r23 = a2 * c3 + L3   # frame-3 x of joint 2 -> COM 3 (a2*c3+a3+S3x)
    M11 = I1 + I2 + I3 + m3 * (ta * ta + tb * tb) + m2 * (tc * tc + a1 * a1 * s2 * s2) + m1 * L1 * L1
    M12 = I2 + I3 + m3 * (ta * r23 + a2 * s3 * tb) + m2 * L2 * tc
    M13 = I3 + m3 * L3 * ta
    M22 = I2 + I3 + m3 * (r23 * r23 + a2 * a2 * s3 * s3) + m2 * L2 * L2
    M23 = I3 + m3 * L3 * r23
    M33 = I3 + m3 * L3 * L3
    return np.array([[M11, M12, M13], [M12, M22, M23], [M13, M23, M33]])


def coriolis_centrifugal(q, qdot, masses=LINK_MASSES, izz=LINK_IZZ,
                         lengths=LINK_LENGTHS, com_offsets=LINK_COM_OFFSETS):
    """Coriolis and centrifugal torques h(q, qdot) (3-vector), so that
    tau = M(q) q'' + h(q, qdot) (no gravity torque in the horizontal plane).

    Appendix D's tau_i (D4-4, D5-4, D6-4) with all theta'' = 0, collected by
    w1^2, w12^2, w123^2 (w12 = q1d + q2d, w123 = q1d + q2d + q3d); grouped as
    Appendix E's OMG[] (lines 1989-1994):
        h1 = [m3 a1 (S23 ta - C23 tb) + m2 a1 S2 (tc - a1 C2)] w1^2
             + [m3 a2 (S3 ta - C3 tb) - m2 a1 S2 L2] w12^2 - m3 L3 tb w123^2
        h2 = [m3 a1 (S23 (a2 C3 + L3) - a2 S3 C23) + m2 a1 S2 L2] w1^2
             + [m3 a2 S3 (a2 C3 + L3) - m3 a2^2 S3 C3] w12^2 - m3 a2 S3 L3 w123^2
        h3 = m3 L3 (a1 S23 w1^2 + a2 S3 w12^2)
    Simplified, the w1^2 coefficient of h1 and h2 is a1 (m3 (a2 S2 + L3 S23)
    + m2 L2 S2). h2 and h3 match Appendix E as printed. Uses the Appendix D
    repairs listed in :func:`mass_matrix`.

    OCR repairs of the Appendix E OMG[0] (lines 1990-1991), checked against
    the D6-4 derivation:
    - "m3*a1*s23*(a-m3*a1*c23*tb" is m3*a1*s23*ta-m3*a1*c23*tb (a "t" read
      as "("; the printed line has an unmatched parenthesis);
    - "-m2*a1*a1*s2*s2*c2" (w1^2 term) is -m2*a1*a1*s2*c2;
    - "-m2*a1*a1*s2*s2*(a2+S2x)" (w12^2 term) is -m2*a1*s2*(a2+S2x) (the
      printed term is dimensionally wrong, kg m^3);
    - "luv = ..." (line 1989) declares the variable used as "tuv" (w123^2).
    """
    qdot = _q3(qdot, "qdot")
    m1, m2, m3 = masses
    g = _grouped_terms(q, lengths, com_offsets)
    a1, a2 = g["a1"], g["a2"]
    L2, L3 = g["L2"], g["L3"]
    s2, c2, s3, c3 = g["s2"], g["c2"], g["s3"], g["c3"]
    s23, c23 = g["s23"], g["c23"]
    ta, tb, tc = g["ta"], g["tb"], g["tc"]
    w1 = qdot[0]
    w12 = qdot[0] + qdot[1]
    w123 = qdot[0] + qdot[1] + qdot[2]
    w1s, w12s, w123s = w1 * w1, w12 * w12, w123 * w123
    r23 = a2 * c3 + L3
    h1 = ((m3 * a1 * (s23 * ta - c23 * tb) + m2 * a1 * s2 * (tc - a1 * c2)) * w1s
          + (m3 * a2 * (s3 * ta - c3 * tb) - m2 * a1 * s2 * L2) * w12s
          - m3 * L3 * tb * w123s)
    h2 = ((m3 * a1 * (s23 * r23 - a2 * s3 * c23) + m2 * a1 * s2 * L2) * w1s
          + (m3 * a2 * s3 * r23 - m3 * a2 * a2 * s3 * c3) * w12s
          - m3 * a2 * s3 * L3 * w123s)
    h3 = m3 * L3 * (a1 * s23 * w1s + a2 * s3 * w12s)
    return np.array([h1, h2, h3])


def inverse_dynamics(q, qdot, qddot, masses=LINK_MASSES, izz=LINK_IZZ,
                     lengths=LINK_LENGTHS, com_offsets=LINK_COM_OFFSETS):
    """Joint torques tau by Appendix D's recursion itself, step by step
    (D1-D3 forward, D4-D6 backward, tip load f_g = n_g = 0), in-plane
    components only (x, y of forces in each link frame, z of moments), with
    the repairs listed in :func:`mass_matrix`. Equals
    ``mass_matrix(q) @ qddot + coriolis_centrifugal(q, qdot)``; kept as a
    literal transcription to cross-check the collected closed forms.
    """
    q, qdot, qddot = _q3(q, "q"), _q3(qdot, "qdot"), _q3(qddot, "qddot")
    m1, m2, m3 = masses
    I1, I2, I3 = izz
    a1, a2, a3 = lengths
    L1, L2, L3 = (a + s for a, s in zip(lengths, com_offsets))
    s2, c2, s3, c3 = np.sin(q[1]), np.cos(q[1]), np.sin(q[2]), np.cos(q[2])
    w1, w12, w123 = qdot[0], qdot[0] + qdot[1], qdot.sum()      # D1-1, D2-1, D3-1
    al1, al12, al123 = qddot[0], qddot[0] + qddot[1], qddot.sum()  # D1-2, D2-2, D3-2
    # D1-3: acceleration of frame-1 origin, in frame 1 (g dropped, see module doc).
    V1x, V1y = -a1 * w1 ** 2, a1 * al1
    # D2-3: Rot2^t V1 + Dev(Delta_2) P2.
    V2x = c2 * V1x + s2 * V1y - a2 * w12 ** 2
    V2y = -s2 * V1x + c2 * V1y + a2 * al12
    # D3-3: Rot3^t V2 + Dev(Delta_3) P3.
    V3x = c3 * V2x + s3 * V2y - a3 * w123 ** 2
    V3y = -s3 * V2x + c3 * V2y + a3 * al123
    # D1-4..D3-5: COM accelerations (V_i + Dev(Delta_i) S_i) and F_i = m_i a_i.
    F1x, F1y = m1 * (V1x - (L1 - a1) * w1 ** 2), m1 * (V1y + (L1 - a1) * al1)
    F2x, F2y = m2 * (V2x - (L2 - a2) * w12 ** 2), m2 * (V2y + (L2 - a2) * al12)
    F3x, F3y = m3 * (V3x - (L3 - a3) * w123 ** 2), m3 * (V3y + (L3 - a3) * al123)
    # D1-6..D3-6: N_i z-components.
    N1z, N2z, N3z = I1 * al1, I2 * al12, I3 * al123
    # D4-1, D4-3, D4-4 (f_g = n_g = 0).
    f3x, f3y = F3x, F3y
    n3z = L3 * F3y + N3z
    tau3 = n3z
    # D5-1, D5-3, D5-4.
    r3fx, r3fy = c3 * f3x - s3 * f3y, s3 * f3x + c3 * f3y   # [Rot3]{f3}
    f2x, f2y = r3fx + F2x, r3fy + F2y
    n2z = n3z + a2 * r3fy + L2 * F2y + N2z
    tau2 = n2z
    # D6-3, D6-4.
    n1z = n2z + a1 * (f2x * s2 + f2y * c2) + L1 * F1y + N1z
    tau1 = n1z
    return np.array([tau1, tau2, tau3])
