// The record's trend plot: its figure is a JSON data block of the page (never a script).
(function () {
  var figure = JSON.parse(document.getElementById("figure").textContent);
  Plotly.newPlot("trend", figure.data, figure.layout, {displaylogo: false, responsive: true});
})();
