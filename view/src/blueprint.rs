//! The layout a first-time user sees: the 3-D scene on the left; on the right the map from
//! above, the time series and the tracking log; the time panel on the sensor's timeline; the
//! recordings list and the selection panel collapsed, so the views get the window. Sent as the
//! active blueprint: every recording opens in this layout.

use rerun::blueprint::components::PanelState;
use rerun::blueprint::{
    Blueprint, BlueprintPanel, Horizontal, SelectionPanel, Spatial2DView, Spatial3DView,
    TextLogView, TimePanel, TimeSeriesView, Vertical,
};

use crate::scene::TIMELINE;

pub fn layout() -> Blueprint {
    let scene = Spatial3DView::new("Map frame").with_origin("world");
    let top = Spatial2DView::new("From above").with_origin("topdown");
    let series = TimeSeriesView::new("Tracking, degeneracy, latency").with_origin("metrics");
    let log = TextLogView::new("Tracking state").with_origin("tracking");
    let right =
        Vertical::new([top.into(), series.into(), log.into()]).with_row_shares([0.45, 0.35, 0.2]);
    Blueprint::new(Horizontal::new([scene.into(), right.into()]).with_column_shares([0.62, 0.38]))
        .with_time_panel(TimePanel::new().with_timeline(TIMELINE))
        .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
        .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
}
