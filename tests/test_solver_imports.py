"""highspy 1.15.x and ortools 9.15 cannot share a process (google/or-tools#5246): keep both
importable and working together with the pinned highspy 1.14."""

import numpy as np


def test_highspy_and_ortools_in_one_process() -> None:
    import highspy
    from ortools.sat.python import cp_model

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = 2, 1
    lp.col_cost_ = np.array([1.0, 2.0])
    lp.col_lower_, lp.col_upper_ = np.zeros(2), np.ones(2)
    lp.row_lower_, lp.row_upper_ = np.array([-np.inf]), np.array([1.0])
    lp.sense_ = highspy.ObjSense.kMaximize
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.array([0, 2], np.int32)
    lp.a_matrix_.index_ = np.array([0, 1], np.int32)
    lp.a_matrix_.value_ = np.array([1.0, 1.0])
    lp.integrality_ = [highspy.HighsVarType.kInteger] * 2
    h.passModel(lp)
    h.run()
    assert h.getModelStatus() == highspy.HighsModelStatus.kOptimal
    assert abs(h.getInfo().objective_function_value - 2.0) < 1e-9

    m = cp_model.CpModel()
    a, b = m.NewBoolVar("a"), m.NewBoolVar("b")
    m.AddAtMostOne([a, b])
    m.Maximize(a + 2 * b)
    s = cp_model.CpSolver()
    s.parameters.num_workers = 2
    assert s.Solve(m) == cp_model.OPTIMAL
    assert s.ObjectiveValue() == 2
