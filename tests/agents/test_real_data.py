"""The real-data table's pieces: the peer's figures read from its file, the best hand-designed row, the note."""
import math

from agents.real_data import best_hand_designed, format_note, peer_rows

PEER = """# Peer
| error model (App_GNSS config) | RMSE h [m] | RMSE 3D [m] | p95 h [m] | max h [m] | CPU s |
|---|---|---|---|---|---|
| gauss | 31.89 | 65.02 | 56.01 | 83.18 | 15 |
| max-sum-mixture, incremental VB (the app's default) | 7.97 | 11.87 | 12.93 | 14.42 | 69 |
"""


def test_peer_rows_are_read_from_the_peer_file(tmp_path):
    p = tmp_path / "librsf.md"
    p.write_text(PEER)
    assert peer_rows(p) == [("gauss", 31.89, 56.01, 83.18),
                            ("max-sum-mixture, incremental VB (the app's default)", 7.97, 12.93, 14.42)]
    assert peer_rows(tmp_path / "absent.md") is None


def _row(rmse, div=0):
    return {"rmse_h_m": rmse, "p95_h_m": rmse, "max_h_m": rmse, "rmse_3d_m": rmse, "diverged": div}


def test_best_hand_designed_leaves_out_spp_oracles_and_diverged_rows():
    rows = {"SPP": _row(1.0), "kf": _row(9.0), "kf-igg3": _row(7.0), "vb-akf": _row(2.0, div=1),
            "oracle-r (truth errors as variances)": _row(3.0)}
    assert best_hand_designed(rows) == ("kf-igg3", 7.0)
    assert best_hand_designed({"SPP": _row(1.0)})[0] is None and math.isnan(best_hand_designed({})[1])


def test_note_names_the_best_method_and_the_consistency_figures():
    cons = {"within_1_5m": 0.2, "within_3m": 0.31, "system_bias_m": {0: 0.0, 1: -5.9}, "offset_enu_m": [1.8, 6.2, 9.6],
            "within_1_5m_offset": 0.27, "within_3m_offset": 0.37, "lower_clock_within_3m": 0.3}
    text = format_note({"rec": {"rows": {"SPP": _row(30.0), "kf": _row(20.0), "kf-fde": _row(8.0)},
                                "consistency": cons}}, 4, 0, 60.0, "python -m agents.real_data")
    assert "Best hand-designed method: `kf-fde`, 8.00 m" in text and "| **kf-fde** | 8.00 |" in text
    assert "R: -5.90 m" in text and "up +9.60 m" in text
