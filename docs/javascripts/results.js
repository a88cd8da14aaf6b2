// clods-bench site: click a results figure to see it at full size in place; click again or press Escape to close.
// Without JavaScript the figure's link opens the PNG file itself. No external resources.
(function () {
  function close() {
    var box = document.querySelector(".clods-lightbox");
    if (box) box.remove();
  }
  document.addEventListener("click", function (event) {
    var link = event.target.closest && event.target.closest(".clods-figure a");
    if (link) {
      event.preventDefault();
      close();
      var box = document.createElement("div");
      box.className = "clods-lightbox";
      var img = document.createElement("img");
      img.src = link.href;
      img.alt = (link.querySelector("img") || {}).alt || "";
      box.appendChild(img);
      box.addEventListener("click", close);
      document.body.appendChild(box);
    }
  });
  document.addEventListener("keydown", function (event) {
    if (event.key === "Escape") close();
  });
})();
