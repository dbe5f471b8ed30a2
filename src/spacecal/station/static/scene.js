// The set-up in 3-D on a calibration's page: the figure the station computed from the files
// on disk (spacecal.station.scene). A browser without WebGL says so; nothing else depends on it.
(function () {
  var target = document.getElementById("scene");
  var source = document.getElementById("scene-figure");
  if (!target || !source) { return; }
  var figure = JSON.parse(source.textContent);
  target.dataset.frame = figure.frame;
  try {
    Plotly.newPlot(target, figure.data, figure.layout, {displaylogo: false, responsive: true});
  } catch (error) {
    target.textContent = "the 3-D view cannot be drawn in this browser (" + error + ")";
  }
}());
